"""The C translators' shared vocabulary: the jaxpr primitives by kind with their C templates, the C types and
literals, a translated value (:class:`Val`), the refusals, and the NumPy evaluation of data-moving primitives on
element ids. Both translators (:mod:`._jaxpr_c`, arrays and loops; :mod:`._scalar_c`, straight-line scalars)
read them from here, so neither reaches into the other's private names."""

from __future__ import annotations

import contextlib
import math
import re
from dataclasses import dataclass

import jax
import numpy as np

from .._frames import eqn_frames, liemefs_own, user_frame

_CTYPES = {np.dtype(np.float64): "double", np.dtype(np.float32): "float", np.dtype(np.int32): "int32_t",
           np.dtype(np.int64): "int64_t", np.dtype(np.uint32): "uint32_t", np.dtype(np.uint8): "uint8_t",
           np.dtype(np.int8): "int8_t", np.dtype(np.bool_): "_Bool"}


class UnsupportedPrimitive(NotImplementedError):
    """A primitive (or a use of one, e.g. a ``while`` under reverse-mode differentiation) the translator has no
    C for. Its text ends with where the user's code traced it: the innermost frame outside liemef and JAX
    (``frames``, innermost first, gathered from the equation and every call around it as the error rises)."""

    def __init__(self, message: str, frames=()):
        super().__init__(message)
        self.message = message
        self.frames = list(frames)

    def __str__(self) -> str:
        where = user_frame(self.frames)
        return f"{self.message} (traced at {where})" if where else self.message

    def __reduce__(self):
        return (type(self), (self.message, self.frames))


@contextlib.contextmanager
def translating(within: list, eqn):
    """Both translators' frame around one equation: ``eqn`` is on ``within`` (the equations being translated,
    outermost first) while it is translated, and an :class:`UnsupportedPrimitive` raised inside gains its frames
    as it rises, so that its text names the user's line."""
    within.append(eqn)
    try:
        yield
    except UnsupportedPrimitive as e:
        e.frames.extend(eqn_frames(eqn))
        raise
    finally:
        within.pop()



EIGH_REFUSED = ("eigh (jnp.linalg.eigh, eigvalsh): the sign of each eigenvector, and the basis of a repeated "
                "eigenvalue's eigenspace, are LAPACK's choice in XLA, which C does not reproduce (eigvalsh's "
                "derivatives read the eigenvectors too); use engine=\"xla\", or a closed form (the eigenvalues of "
                "[[a, b], [b, d]] are (a + d)/2 -+ sqrt(((a - d)/2)**2 + b**2))")
"""Why a user's ``eigh`` has no C: an eigenvector is defined up to its sign (a repeated eigenvalue's up to a
rotation of its eigenspace), and the C engine gives XLA's result bit for bit or none. liemef's own ``eigh``
(the UKF-M's square root of P, whose sigma points come in +- pairs) is translated: :func:`liemefs_own`."""


def ctype(dtype) -> str:
    """The C type of a NumPy dtype."""
    dt = np.dtype(dtype)
    if dt not in _CTYPES:
        raise UnsupportedPrimitive(f"dtype {dt} has no C type here (expected one of {sorted(map(str, _CTYPES))})")
    return _CTYPES[dt]


def literal(x, dtype) -> str:
    """A C literal for one value of ``dtype`` (NaN and infinities by ``<math.h>``'s macros)."""
    dt = np.dtype(dtype)
    if dt == np.bool_:
        return "1" if bool(x) else "0"
    if dt.kind in "iu":
        v = int(x)
        return f"INT64_C({v})" if dt.itemsize == 8 else (f"({v})" if v < 0 else str(v))
    v = float(x)
    if math.isnan(v):
        return "NAN"
    if math.isinf(v):
        return "INFINITY" if v > 0 else "(-INFINITY)"
    s = repr(v)
    if "e" not in s and "." not in s and "inf" not in s:
        s += ".0"
    return f"({s})" if v < 0 or s.startswith("-") else s


@dataclass
class Val:
    """A value of the C program: a named array, or a known constant (``const``)."""

    shape: tuple
    dtype: np.dtype
    name: str | None = None
    const: np.ndarray | None = None

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))


# --- elementwise primitives: C expressions of the operands' elements a, b, c --------------------------------
FLOAT_UNARY = {
    "neg": "-({a})", "sin": "sin({a})", "cos": "cos({a})", "tan": "tan({a})", "asin": "asin({a})",
    "acos": "acos({a})", "atan": "atan({a})", "sinh": "sinh({a})", "cosh": "cosh({a})", "tanh": "tanh({a})",
    "asinh": "asinh({a})", "acosh": "acosh({a})", "atanh": "atanh({a})", "exp": "exp({a})", "exp2": "exp2({a})",
    "log": "log({a})", "log1p": "log1p({a})", "expm1": "expm1({a})", "sqrt": "sqrt({a})",
    "rsqrt": "(1.0 / sqrt({a}))", "cbrt": "cbrt({a})", "abs": "fabs({a})", "floor": "floor({a})",
    "ceil": "ceil({a})", "is_finite": "isfinite({a})", "logistic": "(1.0 / (1.0 + exp(-({a}))))",
    "square": "(({a}) * ({a}))", "erf": "erf({a})", "erfc": "erfc({a})", "lgamma": "lgamma({a})",
    "sign": "lm_sign({a})", "stop_gradient": "{a}", "copy": "{a}", "copy_p": "{a}", "real": "{a}",
    "reduce_precision": "{a}", "optimization_barrier": "{a}", "round": "round({a})",
}
ROUND_EVEN = {"rint": "rint({a})"}  # ``round`` to nearest even (rounding_method 1), in the default rounding mode
INT_UNARY = {"neg": "-({a})", "abs": "(({a}) < 0 ? -({a}) : ({a}))", "not": "~({a})", "stop_gradient": "{a}",
              "copy": "{a}", "copy_p": "{a}", "sign": "((({a}) > 0) - (({a}) < 0))", "square": "(({a}) * ({a}))"}
BOOL_UNARY = {"not": "!({a})", "stop_gradient": "{a}", "copy": "{a}", "copy_p": "{a}"}
BINARY = {
    "add": "({a}) + ({b})", "add_any": "({a}) + ({b})", "sub": "({a}) - ({b})", "mul": "({a}) * ({b})",
    "div": "({a}) / ({b})", "lt": "({a}) < ({b})", "le": "({a}) <= ({b})", "gt": "({a}) > ({b})",
    "ge": "({a}) >= ({b})", "eq": "({a}) == ({b})", "ne": "({a}) != ({b})",
}
FLOAT_BINARY = {"max": "lm_max({a}, {b})", "min": "lm_min({a}, {b})", "pow": "pow({a}, {b})",
                 "lt_to": "lm_lt_to({a}, {b})", "le_to": "!lm_lt_to({b}, {a})", "eq_to": "lm_eq_to({a}, {b})",
                 "atan2": "atan2({a}, {b})", "rem": "fmod({a}, {b})", "nextafter": "nextafter({a}, {b})"}
INT_BINARY = {"max": "(({a}) > ({b}) ? ({a}) : ({b}))", "min": "(({a}) < ({b}) ? ({a}) : ({b}))",
               "rem": "({a}) % ({b})", "and": "({a}) & ({b})", "or": "({a}) | ({b})", "xor": "({a}) ^ ({b})",
               "shift_left": "({a}) << ({b})"}
def int_division(op: str, a: str, b: str, dtype) -> str:
    """C for an integer ``div`` or ``rem`` of the expressions ``a``, ``b`` with XLA's results where C has
    none: x / 0 = -1 (all bits set), x % 0 = x, and for signed MIN / -1 = MIN (wrapped), MIN % -1 = 0. (A
    plain C ``/`` is undefined there: the x86 division traps, SIGFPE, and the process dies.)"""
    dt = np.dtype(dtype)
    T = ctype(dt)
    if op == "div":
        minus = f"({b}) == -1 ? ({T})((u{T})0 - (u{T})({a})) : " if dt.kind == "i" else ""
        return f"(({b}) == 0 ? ({T})-1 : {minus}({a}) / ({b}))"
    minus = f"({b}) == -1 ? ({T})0 : " if dt.kind == "i" else ""
    return f"(({b}) == 0 ? ({a}) : {minus}({a}) % ({b}))"


def shift_left(a: str, b: str, dtype) -> str:
    """C for ``a << b`` on the integer ``dtype`` with XLA's result where C has none: 0 for a shift outside
    [0, bits) (C leaves it undefined, and x86 shifts by b mod 32), and the bits of a negative ``a`` shifted as
    they are (through the unsigned type)."""
    dt = np.dtype(dtype)
    T = ctype(dt)
    U = f"u{T}" if dt.kind == "i" else T
    return f"(({b}) < 0 || ({b}) >= {8 * dt.itemsize} ? ({T})0 : ({T})(({U})({a}) << ({b})))"


def float_to_int(a: str, dtype) -> str:
    """C for the float expression ``a`` converted to the integer ``dtype`` as XLA converts: truncated, NaN to 0,
    saturated at the type's limits (C's cast is undefined there: x86 gives INT_MIN for NaN and for 1e10)."""
    dt = np.dtype(dtype)
    T, info = ctype(dt), np.iinfo(dt)
    name = T[:-2].upper()
    low = f"({T})0" if info.min == 0 else f"{name}_MIN"
    return (f"(({a}) != ({a}) ? ({T})0 : ({a}) >= {float(info.max)!r} ? {name}_MAX : "
            f"({a}) <= {float(info.min)!r} ? {low} : ({T})({a}))")


def saturated(x: np.ndarray, dtype) -> np.ndarray:
    """NumPy's float array ``x`` converted to the integer ``dtype`` as :func:`float_to_int` (and XLA) does."""
    info = np.iinfo(dtype)
    with np.errstate(all="ignore"):
        y = np.trunc(np.where(np.isnan(x), 0.0, x))
        out = np.where(y >= float(info.max), info.max, np.where(y <= float(info.min), info.min, 0)).astype(dtype)
        inside = (y < float(info.max)) & (y > float(info.min))
        out[inside] = y[inside].astype(dtype)
    return out


BOOL_BINARY = {"and": "({a}) && ({b})", "or": "({a}) || ({b})", "xor": "({a}) != ({b})",
                "max": "({a}) || ({b})", "min": "({a}) && ({b})"}

STRUCTURAL = {"broadcast_in_dim", "reshape", "squeeze", "expand_dims", "transpose", "slice", "pad", "concatenate",
               "rev", "stack", "unstack", "split", "gather", "scatter", "scatter-add", "scatter_add",
               "dynamic_slice", "dynamic_update_slice"}
REDUCE = {"reduce_sum": "sum", "reduce_max": "max", "reduce_min": "min", "reduce_prod": "prod",
           "reduce_and": "and", "reduce_or": "or", "argmax": "argmax", "argmin": "argmin"}
CALLS = {"jit", "pjit", "closed_call", "core_call", "custom_jvp_call", "custom_vjp_call", "custom_vjp_call_jaxpr",
          "checkpoint", "remat", "remat2", "custom_lin"}
CONTROL = {"while", "cond", "scan"}
_LINALG = {"dot_general", "lu", "lu_pivots_to_permutation", "triangular_solve", "custom_linear_solve",
           "select_n", "clamp",
           "convert_element_type", "integer_pow", "iota", "sort", "cholesky"}
CUMULATIVE = {"cumsum", "cumprod", "cummax", "cummin"}

PRIMITIVES: frozenset[str] = frozenset(
    set(FLOAT_UNARY) | set(INT_UNARY) | set(BOOL_UNARY) | set(BINARY) | set(FLOAT_BINARY) | set(INT_BINARY)
    | STRUCTURAL | set(REDUCE) | CALLS | CONTROL | _LINALG | CUMULATIVE)
"""The primitives the translators cover, in every form (run-time indices, run-time data) by the scalar
translator (:mod:`._scalar_c`, the engine's and the default export's). Not ``eigh``: only liemef's own, whose
result does not depend on LAPACK's choice of eigenvectors, is translated (:data:`EIGH_REFUSED`). The array translator
(:func:`jaxpr_to_c`) covers those of :data:`SCALAR_ONLY` only on known constants, gathers with run-time
indices only along one axis and ``scan`` only in ``fori_loop``'s form."""

SCALAR_ONLY: frozenset[str] = frozenset({"sort", "argmax", "argmin", "cholesky", "lt_to", "le_to", "eq_to",
                                         "dynamic_slice", "dynamic_update_slice", "scatter", "scatter-add",
                                         "scatter_add"} | CUMULATIVE)
"""Primitives that the array translator takes only where their data (or indices) are known constants."""

HELPERS = r"""
static inline double lm_max(double a, double b)
{ return isunordered(a, b) ? a + b : (a > b ? a : (b > a ? b : (signbit(a) ? b : a))); }
static inline double lm_min(double a, double b)
{ return isunordered(a, b) ? a + b : (a < b ? a : (b < a ? b : (signbit(a) ? a : b))); }
static inline double lm_sign(double a) { return a > 0.0 ? 1.0 : (a < 0.0 ? -1.0 : a); }
static inline _Bool lm_lt_to(double a, double b)
{ union { double d; int64_t i; } x, y; x.d = a; y.d = b; /* lax.sort's total order: flip the negatives */
  x.i ^= (int64_t)((uint64_t)(x.i >> 63) >> 1); y.i ^= (int64_t)((uint64_t)(y.i >> 63) >> 1); return x.i < y.i; }
static inline _Bool lm_eq_to(double a, double b)
{ union { double d; int64_t i; } x, y; x.d = a; y.d = b; return x.i == y.i; }
"""
"""Static inline functions a generated source may start with (XLA's NaN-propagating max and min, sign, the
total order of floats that ``lax.sort`` and ``searchsorted`` compare by). The max and min test for a NaN with
C99's ``isunordered``, one comparison where ``a != a || b != b`` compiled to two and a branch: the TSE(2) step
(88 of them) 4-6 % faster on a Zen 4, the same values. Of +0 and -0, XLA's max is +0 and its min -0, in
either order (C's ``a > b ? a : b`` returned b)."""


def helpers_used(*texts: str) -> str:
    """The lines of :data:`HELPERS` whose function ``texts`` call: an unused static function is a warning
    (``-Wunused-function``) in clang, even when inline, and the exported C compiles with ``-Wall -Werror``."""
    body = "\n".join(texts)
    functions = re.split(r"\n(?=static inline)", HELPERS.strip())
    return "\n".join(fn for fn in functions
                     if re.search(r"\b" + re.search(r"\b(lm_\w+)\(", fn).group(1) + r"\(", body))


def own_precision(params: dict, dtype) -> None:
    """``reduce_precision`` has C only at its operand's own precision (or wider), where it changes nothing: JAX's
    checkpointing inserts it so. A narrower one (bfloat16 or float32 rounding of a float64) raises."""
    fi = np.finfo(dtype)
    e, m = int(params["exponent_bits"]), int(params["mantissa_bits"])
    if e < fi.nexp or m < fi.nmant:
        raise UnsupportedPrimitive(f"reduce_precision to {e} exponent and {m} mantissa bits of a {np.dtype(dtype)} "
                                   f"(only at its own {fi.nexp} and {fi.nmant}, where it changes nothing)")


def refuse_choice(eqn, within) -> None:
    """Raise :class:`UnsupportedPrimitive` for an ``eigh`` that is not liemef's own (:data:`EIGH_REFUSED`):
    ``within`` are the equations around it, outermost first, whose frames say who traced it."""
    frames = [f for e in [eqn, *reversed(within)] for f in eqn_frames(e)]
    if not liemefs_own(frames):
        raise UnsupportedPrimitive(EIGH_REFUSED)


def _subjaxpr(params: dict, *keys):
    for k in keys:
        if k in params:
            j = params[k]
            return (j.jaxpr, j.consts) if hasattr(j, "consts") else (j, ())
    raise UnsupportedPrimitive(f"call without a jaxpr (params {sorted(params)})")


def _pad(x, pv, config):
    for ax, (lo, hi, interior) in enumerate(config):
        n = x.shape[ax]
        size = n + max(n - 1, 0) * interior
        shape = list(x.shape)
        shape[ax] = size
        y = np.full(shape, pv, dtype=x.dtype)
        idx = [slice(None)] * x.ndim
        idx[ax] = slice(0, size, interior + 1)
        y[tuple(idx)] = x
        # lo / hi: pad (positive) or crop (negative)
        if lo < 0:
            y = np.take(y, range(-lo, y.shape[ax]), axis=ax)
        if hi < 0:
            y = np.take(y, range(0, y.shape[ax] + hi), axis=ax)
        widths = [(0, 0)] * x.ndim
        widths[ax] = (max(lo, 0), max(hi, 0))
        x = np.pad(y, widths, constant_values=pv)
    return x


def _broadcast_in_dim(x, shape, dims):
    expanded = [1] * len(shape)
    for d, n in zip(dims, x.shape, strict=True):
        expanded[d] = n
    return np.broadcast_to(x.reshape(expanded), tuple(shape))



def _scatter_window(xs, p):
    """A ``scatter`` (set) of one window at one known index vector inside the operand, as ``x.at[i:i+a, j:j+b]
    .set(u)`` traces: the operand with the window replaced; None for any other scatter (batched indices,
    batching dims, an update function, a window that does not fit: XLA decides those)."""
    x, idx, upd = xs
    dn = p["dimension_numbers"]
    if (p.get("update_jaxpr") is not None or dn.operand_batching_dims or idx.ndim != 1
            or upd.ndim != len(dn.update_window_dims) or idx.size != len(dn.scatter_dims_to_operand_dims)):
        return None
    window, sizes = [], iter(upd.shape)
    for d in range(x.ndim):
        window.append(1 if d in dn.inserted_window_dims else next(sizes, None))
    if None in window or next(sizes, None) is not None:
        return None
    start = [0] * x.ndim
    for i, d in zip(idx.tolist(), dn.scatter_dims_to_operand_dims, strict=True):
        start[d] = int(i)
    if any(s < 0 or s + w > n for s, w, n in zip(start, window, x.shape, strict=True)):
        return None
    out = x.copy()
    out[tuple(slice(s, s + w) for s, w in zip(start, window, strict=True))] = upd.reshape(window)
    return [out]

# NumPy versions of the primitives that move elements, for index maps and constant folding (an eager JAX call
# costs milliseconds each: thousands of them made an export take seconds)
_NP_STRUCTURAL = {
    "broadcast_in_dim": lambda xs, p: [_broadcast_in_dim(xs[0], p["shape"], p["broadcast_dimensions"])],
    "reshape": lambda xs, p: [xs[0].reshape(p["new_sizes"])] if p.get("dimensions") is None else None,
    "squeeze": lambda xs, p: [np.squeeze(xs[0], axis=tuple(p["dimensions"]))],
    "expand_dims": lambda xs, p: [np.expand_dims(xs[0], tuple(p["dimensions"]))],
    "transpose": lambda xs, p: [np.transpose(xs[0], p["permutation"])],
    "slice": lambda xs, p: [xs[0][tuple(slice(a, b, c) for a, b, c in zip(
        p["start_indices"], p["limit_indices"], p["strides"] or [1] * xs[0].ndim, strict=True))]],
    "concatenate": lambda xs, p: [np.concatenate(xs, axis=p["dimension"])],
    "pad": lambda xs, p: [_pad(xs[0], xs[1], p["padding_config"])],
    "rev": lambda xs, p: [np.flip(xs[0], axis=tuple(p["dimensions"]))],
    "stack": lambda xs, p: [np.stack(xs, axis=p["axis"])],
    "unstack": lambda xs, p: [np.take(xs[0], i, axis=p["axis"]) for i in range(xs[0].shape[p["axis"]])],
    "split": lambda xs, p: np.split(xs[0], np.cumsum(p["sizes"])[:-1].astype(int), axis=p["axis"]),
    "scatter": _scatter_window,
}
_NP_ELEMENTWISE = {
    "add": np.add, "add_any": np.add, "sub": np.subtract, "mul": np.multiply, "neg": np.negative,
    "eq": np.equal, "ne": np.not_equal, "lt": np.less, "le": np.less_equal, "gt": np.greater,
    "ge": np.greater_equal, "and": lambda a, b: a & b, "or": lambda a, b: a | b, "not": np.invert,
    "sin": np.sin, "cos": np.cos, "sqrt": np.sqrt, "abs": np.abs, "exp": np.exp, "log": np.log,
    "max": lambda a, b: _extremum(a, b, np.maximum), "min": lambda a, b: _extremum(a, b, np.minimum),
    "stop_gradient": lambda a: a, "is_finite": np.isfinite,
}


def _extremum(a: np.ndarray, b: np.ndarray, fn) -> np.ndarray:
    """NumPy's ``maximum``/``minimum`` with XLA's signed zeros: max(-0, +0) is +0 and min(-0, +0) -0 in either
    order (NumPy returns its second operand)."""
    out = fn(a, b)
    if out.dtype.kind != "f":
        return out
    ties = (a == b) & (np.signbit(a) != np.signbit(b))
    return np.where(ties, np.asarray(0.0 if fn is np.maximum else -0.0, out.dtype), out)


def np_eval(name: str, params: dict, xs: list[np.ndarray], out_dtypes) -> list[np.ndarray] | None:
    """The primitive on NumPy arrays, or None where NumPy's version could differ from XLA's."""
    if name in _NP_STRUCTURAL:
        out = _NP_STRUCTURAL[name](xs, params)
        return None if out is None else [np.asarray(o) for o in out]
    if name in _NP_ELEMENTWISE:
        with np.errstate(all="ignore"):
            out = _NP_ELEMENTWISE[name](*xs)
        return [np.asarray(out, out_dtypes[0])]
    if name == "div" and all(x.dtype.kind == "f" for x in xs):
        with np.errstate(all="ignore"):
            return [np.asarray(xs[0] / xs[1], out_dtypes[0])]
    if name == "select_n":
        return [np.asarray(np.choose(xs[0].astype(int), xs[1:]), out_dtypes[0])]
    if name == "convert_element_type":
        if xs[0].dtype.kind == "f" and np.dtype(out_dtypes[0]).kind in "iu":
            return None
        return [xs[0].astype(out_dtypes[0])]
    if name == "iota":
        shape, dim = params["shape"], params["dimension"]
        ar = np.arange(shape[dim], dtype=params["dtype"]).reshape([-1 if d == dim else 1 for d in range(len(shape))])
        return [np.broadcast_to(ar, shape).copy()]
    if name == "integer_pow" and (xs[0].dtype.kind == "f" or params["y"] >= 0):
        return [np.asarray(integer_pow(xs[0], params["y"]), out_dtypes[0])]
    if name == "reduce_sum" and (xs[0].dtype.kind in "iu" or exact_sum(xs[0])):
        return [np.asarray(np.sum(xs[0], axis=tuple(params["axes"])), out_dtypes[0])]
    return None


def integer_pow(x: np.ndarray, y: int) -> np.ndarray:
    """``x ** y`` as XLA computes it (jax's lowering of ``integer_pow``: the same products, hence the same bits;
    its short forms for y = 2, 3 and -1 are these products too, as multiplication commutes)."""
    if y == 0:
        return np.ones_like(x)
    with np.errstate(all="ignore"):  # overflow and 0 ** -1 as XLA: inf, quietly
        recip, y, acc = y < 0, abs(y), None
        while y > 0:
            if y & 1:
                acc = x if acc is None else acc * x
            y >>= 1
            if y > 0:
                x = x * x
        return np.ones_like(acc) / acc if recip else acc.copy()


def exact_sum(x: np.ndarray) -> bool:
    """Whether a float64 sum of ``x`` is the same in any order: whole numbers, their magnitudes summing below
    2^53, and no -0 (whose sign the order decides; XLA's order of summation is its own)."""
    if x.dtype != np.float64:
        return False
    with np.errstate(all="ignore"):
        return bool(np.all(np.isfinite(x)) and np.all(x == np.round(x)) and np.abs(x).sum() < 2.0**53
                    and not np.any((x == 0) & np.signbit(x)))


def subjaxprs(params: dict):
    """The jaxprs among an equation's parameters (open jaxprs; a ClosedJaxpr's ``.jaxpr``)."""
    for v in params.values():
        for sub in (v if isinstance(v, list | tuple) else [v]):
            if hasattr(sub, "jaxpr") and hasattr(sub, "consts"):
                yield sub.jaxpr
            elif hasattr(sub, "eqns"):
                yield sub


def jaxpr_size(jaxpr) -> int:
    """Equations in ``jaxpr``, nested ones included."""
    return sum(1 + sum(jaxpr_size(s) for s in subjaxprs(e.params)) for e in jaxpr.eqns)


def index_mode(params) -> str:
    """A gather's or scatter's out-of-range rule: ``"clip"`` (clamped; also XLA's own rule for a gather that
    promises in-range indices) or ``"fill"`` (a gather fills, a scatter drops: ``FILL_OR_DROP``, and XLA's own
    rule for a scatter that promises)."""
    mode = str(params.get("mode", "")).rsplit(".", 1)[-1]
    if mode == "CLIP":
        return "clip"
    if mode == "FILL_OR_DROP":
        return "fill"
    if mode in ("PROMISE_IN_BOUNDS", ""):
        return "fill" if "update_jaxpr" in params else "clip"
    raise UnsupportedPrimitive(f"gather/scatter mode {mode}")


def fill_value(fill, dtype):
    """A filling gather's value (jax's default for None: NaN, the most negative or the largest integer, True)."""
    dt = np.dtype(dtype)
    if fill is not None:
        return np.asarray(fill, dt).item()
    if dt.kind == "f":
        return np.nan
    if dt == np.bool_:
        return True
    return np.iinfo(dt).min if dt.kind == "i" else np.iinfo(dt).max


def take_layout(params, x_shape, idx_shape, shape):
    """The layout of a gather with indices known at run time along one axis (``jnp.take``, ``x[idx]``, the
    pivoting in ``linalg.solve``, also batched by ``vmap``/``jacfwd``), the one form both translators take:
    the axis ``a``, and per output element (row-major) the operand index with axis a at 0 and the index
    array's element (its multi-index, without the trailing 1) that sets axis a."""
    dn = params["dimension_numbers"]
    sizes = tuple(int(v) for v in params["slice_sizes"])
    smap = tuple(int(v) for v in dn.start_index_map)
    collapsed = tuple(int(v) for v in dn.collapsed_slice_dims)
    offset_dims = tuple(int(v) for v in dn.offset_dims)
    ok = (len(smap) == 1 and not dn.operand_batching_dims and sizes[smap[0]] == 1
          and all(sz == n for d, (sz, n) in enumerate(zip(sizes, x_shape, strict=True)) if d != smap[0])
          and tuple(idx_shape[-1:]) == (1,) and set(collapsed) <= {smap[0]})
    if not ok:
        raise UnsupportedPrimitive(f"gather with indices known only at run time (only along one axis, "
                                   f"jnp.take's form; got {dn}, slice sizes {sizes})")
    a = smap[0]
    op_dims = [d for d in range(len(x_shape)) if d not in collapsed]  # operand dims in the output, in order
    batch_pos = [k for k in range(len(shape)) if k not in offset_dims]
    places = []
    for oi in np.ndindex(*shape):
        src = [0] * len(x_shape)
        for k, d in zip(offset_dims, op_dims, strict=True):
            src[d] = oi[k] if d != a else 0
        places.append((tuple(src), tuple(oi[k] for k in batch_pos)))
    return a, places


def inlined(name: str, params: dict, ins: list):
    """For a call (``jit``, ``custom_jvp_call``, ...) or a ``custom_linear_solve``: the jaxpr to emit in its
    place, its constants and its arguments (the solve's own jaxpr on its constants and right-hand side)."""
    if name == "custom_linear_solve":
        lengths, jaxprs = params["const_lengths"], params["jaxprs"]
        off = lengths.matvec + lengths.vecmat
        b = ins[off + lengths.solve + lengths.transpose_solve:]
        return jaxprs.solve.jaxpr, jaxprs.solve.consts, list(ins[off:off + lengths.solve]) + list(b)
    if name in ("custom_jvp_call", "custom_vjp_call", "custom_vjp_call_jaxpr", "closed_call", "core_call"):
        jaxpr, consts = _subjaxpr(params, "call_jaxpr", "fun_jaxpr", "jaxpr")
    else:
        jaxpr, consts = _subjaxpr(params, "jaxpr", "call_jaxpr")
    return jaxpr, consts, list(ins[len(ins) - len(jaxpr.invars):])


def element_ids(eqn, ins) -> tuple[list[int], dict, list[np.ndarray], bool]:
    """A data-moving equation run on element ids: operand j's element e is id ``bases[j] + e`` (ids from 1;
    0 means zero). Returns the data operands, their bases, each output's ids, and whether the equation adds
    its updates into the operand (a scatter-add, whose ids say where each update lands). The other operands
    (indices) must be known: ``ins[j].const``."""
    params = eqn.params
    data = list(range(len(ins)))
    name = eqn.primitive.name
    if name == "gather":
        data = [0]
    elif name in ("scatter", "scatter-add", "scatter_add"):
        data = [0, 2]
    elif name in ("dynamic_slice",):
        data = [0]
    elif name == "dynamic_update_slice":
        data = [0, 1]
    for j, v in enumerate(ins):
        if j not in data and v.const is None:
            raise UnsupportedPrimitive(f"{name} with indices known only at run time")
    if name in ("scatter-add", "scatter_add") and not params.get("unique_indices", False):
        raise UnsupportedPrimitive("scatter-add with possibly repeated indices")
    # ids in the data's own dtype where it is an integer (a scatter's update function is typed), else float64
    kinds = {np.dtype(ins[j].dtype) for j in data}
    only = next(iter(kinds)) if len(kinds) == 1 else None
    id_dtype = only if only is not None and only.kind in "iu" else np.dtype(np.float64)
    if name.startswith("scatter") and np.dtype(np.bool_) in kinds:
        raise UnsupportedPrimitive(f"{name} of booleans")
    bases, args, b = {}, [], 1
    for j, v in enumerate(ins):
        if j in data:
            bases[j] = b
            args.append(np.arange(b, b + v.size, dtype=id_dtype).reshape(v.shape))
            b += v.size
        else:
            args.append(np.asarray(v.const, v.dtype))
    if name in ("scatter-add", "scatter_add"):
        # ids cannot be added: a scatter (set) with unique indices moves the same elements
        outs = _scatter_window(args, {**params, "update_jaxpr": None})
        if outs is None:
            with jax.ensure_compile_time_eval():
                outs = [jax.lax.scatter_p.bind(*args, **params)]
        add_into = True
    else:
        outs = np_eval(name, params, args, [np.float64] * len(eqn.outvars))
        if outs is None:
            with jax.ensure_compile_time_eval():
                outs = eqn.primitive.bind(*args, **params)
            outs = outs if eqn.primitive.multiple_results else [outs]
        add_into = False
    return data, bases, [np.asarray(o).ravel().astype(np.int64) for o in outs], add_into
