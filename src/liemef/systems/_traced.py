"""The user's functions of a system (dynamics, outputs, residuals), checked where they are first traced.

A system's functions are pure JAX functions that the filters trace, differentiate and compile. What a function
gets wrong shows at its first trace: it raises (NumPy, ``float()`` or an ``if`` on a traced value included), it
returns something that is no array, complex, integer or boolean values, a scalar where a vector is expected, or
the wrong number of components. :func:`check_traced` traces it abstractly (``jax.eval_shape``: no computation)
when the system is built and refuses each of these with a ValueError that names the function (its sensor, its
role and its ``__qualname__``) and what came back; an exception raised inside the function is chained
(``raise ... from``). Values show only when the function runs: the filter's :meth:`~liemef.filters.AbstractFilter.init`
evaluates the outputs and residuals once at its initial state and refuses by name (:func:`check_finite`) an
output that is NaN there (undefined) and a residual that is not finite at ``y = h``, where it must be 0. An
infinite output is a singularity of the model (``1 / z`` on ``z = 0``): it passes, since an interval without that
sensor's sample does not use it; a run that uses it fails as non-finite, and its message names the function.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

CONCRETIZATION = (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError,
                  jax.errors.TracerIntegerConversionError)
"""What JAX raises when a function needs the value of a traced array (NumPy on it, ``float()``, an ``if``)."""


def function_name(fn) -> str:
    """How messages name ``fn``: its ``__qualname__`` (``<lambda>`` for a lambda, ``Class.method``) with the file
    and line it is defined at, else its type's name (a callable object, a ``functools.partial``)."""
    name = getattr(fn, "__qualname__", None)
    if isinstance(name, str):
        code = getattr(fn, "__code__", None)
        return name if code is None else f"{name} ({Path(code.co_filename).name}, line {code.co_firstlineno})"
    inner = getattr(fn, "func", None)  # functools.partial
    return f"partial({function_name(inner)})" if callable(inner) else type(fn).__name__


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else ""


def _struct(out):
    """The ShapeDtypeStruct of an output, a list or tuple of scalars taken as the vector ``jnp.asarray`` makes
    of it; None for anything else."""
    if isinstance(out, jax.ShapeDtypeStruct):
        return out
    if isinstance(out, list | tuple) and out and all(isinstance(o, jax.ShapeDtypeStruct) and o.shape == ()
                                                     for o in out):
        return jax.ShapeDtypeStruct((len(out),), jnp.result_type(*(o.dtype for o in out)))
    return None


def _shape(s: tuple) -> str:
    return f"a scalar (shape {s})" if s == () else f"shape {s}"


def check_traced(where: str, fn, args: tuple, shape: tuple[int, ...] | None, *, scalar: bool = False,
                 given: str = "", meaning: str = "") -> jax.ShapeDtypeStruct:
    """Trace ``fn(*args)`` abstractly and return the ShapeDtypeStruct of what it returns; a ValueError naming
    ``where`` (e.g. ``"sensor 'gps': residual"``) and the function when it raises while traced (chained), returns
    no array, complex, integer or boolean values, or a shape other than ``shape`` (None: any vector; ``scalar``:
    a scalar also passes for a one-component vector). ``given`` says what it was traced with, ``meaning`` what
    the expected shape holds."""
    name = f"{where} {function_name(fn)}"
    expected = (_shape(shape) if shape is not None else "a vector") + (f" ({meaning})" if meaning else "")
    try:
        out = jax.eval_shape(fn, *args)
    except CONCRETIZATION as err:
        raise ValueError(f"{name} failed when traced{given}: {type(err).__name__}: {_first_line(err)} (it needs the "
                         "value of a traced array: NumPy, float() or an if on one; write it with jax.numpy, "
                         "jnp.where for a branch)") from err
    except Exception as err:  # the user's function: whatever it raised, named and chained
        raise ValueError(f"{name} failed when traced{given}: {type(err).__name__}: {_first_line(err)}") from err
    s = _struct(out)
    if s is None:
        shown = repr(out) if len(repr(out)) < 200 else repr(out)[:200] + "..."
        raise ValueError(f"{name}: expected an array ({expected}), got {type(out).__name__} {shown}")
    if not jnp.issubdtype(s.dtype, jnp.floating):
        kind = "complex" if jnp.issubdtype(s.dtype, jnp.complexfloating) else (
            "boolean" if s.dtype == jnp.bool_ else "integer")
        raise ValueError(f"{name}: expected real floating-point values, got {kind} values (dtype {s.dtype}, "
                         f"{_shape(s.shape)})" + (" (write constants as floats, 1.0 not 1)" if kind == "integer"
                                                  else ""))
    ok = (s.ndim == 1 if shape is None else s.shape == shape) or (scalar and s.shape == () and shape == (1,))
    if not ok:
        raise ValueError(f"{name}: expected {expected}, got {_shape(s.shape)}")
    return s


def is_traced(tree) -> bool:
    """Whether any leaf of ``tree`` is a JAX tracer (inside jit, vmap or grad: no values to check)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


def array_module(*trees):
    """NumPy where no leaf of ``trees`` is traced (:func:`is_traced`), jax.numpy where one is (under ``jit``,
    ``vmap`` or ``grad``). A system's constant matrices are read by its construction's checks and by each
    filter's: outside a trace, each jax.numpy operation on a new shape is an XLA compile of its own (about 40 ms
    of CPU each), which NumPy computes with the same values."""
    return jnp if is_traced(trees) else np


def at_state(state: str, t) -> str:
    """Where a value was evaluated, for a message: ``"at the initial state"``, with its time unless 0."""
    return f"at {state}" + (f" (t = {float(t):g})" if float(t) else "")


def check_finite(where: str, fn, value, at: str, *, singular: bool = False) -> np.ndarray:
    """``value`` (what ``fn`` returned) as a NumPy array; a ValueError naming ``where``, the function and the
    values when they are not all finite ``at`` the point said. ``singular``: an infinity passes (a singularity of
    the model, e.g. ``1 / z`` on ``z = 0``), NaN does not."""
    v = np.asarray(value)
    bad = np.isnan(v) if singular else ~np.isfinite(v)
    if np.any(bad):
        shown = np.array2string(v, precision=4, threshold=12)
        expected = "numbers, not NaN (undefined there)" if singular else "finite real numbers"
        raise ValueError(f"{where} {function_name(fn)} returned {shown} {at}; expected {expected}")
    return v
