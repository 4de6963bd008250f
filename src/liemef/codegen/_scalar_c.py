r"""C99 for a jaxpr, one scalar at a time: the fast translator of :func:`liemef.codegen.export_c`.

Every array of the jaxpr becomes an array of *scalar nodes* (a NumPy object array of node ids), every
primitive builds nodes element by element, and the C is straight-line code, one ``const`` local per node.
On the way, what the array translator (:mod:`._jaxpr_c`) leaves to the C compiler is done here, where the
structure is still visible:

* **constants fold**, and an operation is simplified only where the result is the same bits for every value
  of its operands, NaN, infinities and the sign of zero included (:meth:`ScalarTranslator._simplify`):
  ``1 * x = x``, ``x - 0 = x``, ``x + (-0) = x``. ``0 * x`` is computed (NaN for an infinite or NaN x, -0 for
  a negative one), and so are ``x + 0`` (+0 for x = -0) and ``0 / x``. The C is then XLA's computation, also
  where a Jacobian's or a Hessian's structural zero meets a NaN. XLA's own rewrites are taken as XLA makes
  them: a product with a boolean array converted to floats (``jacfwd``'s one-hot basis) is a select, NaN
  times a false is 0 (:meth:`ScalarTranslator._masked`); ``x + 0`` and ``x - 0`` with a whole array of
  known zeros are x; a sum of two terms or more (``reduce_sum``, ``dot_general``, ``cumsum``) starts from
  +0, so it is never -0; max and min order -0 below +0.
* **common subexpressions** are formed once (hash-consing), and data movement (broadcasts, reshapes,
  transposes, slices, gathers with known indices) is free: it only rearranges node ids.
* **dead code** is never emitted: only the nodes the outputs (and loop tests) need are written.

Data known only at run time is handled by selects, which every backend (the lane code too) has: a gather, a
scatter or a dynamic slice at run-time indices is a chain of selects over the places the index can take
(clamped, or filled and dropped, as XLA's ``mode`` says); ``argmax``/``argmin`` a chain of comparisons;
``sort`` an odd-even transposition network (stable, in ``lax.sort``'s total order of floats); ``cumsum`` and
its kin running sums; ``cholesky`` the unrolled factorization, NaN where XLA's is.

Control flow keeps its shape: a ``while`` is a C loop over carry variables, with its test and body in their
own scopes, and a ``cond`` a ``switch`` (writing only the results that are read). A ``scan`` without
per-iteration inputs or outputs (``fori_loop``'s) is a counted C loop; one with them (``lax.scan``, a
``fori_loop`` under reverse-mode differentiation, ``expm``'s squarings) is unrolled, up to
:data:`UNROLL_MAX` equations. Calls are inlined, so that their constants fold and the zeros of
their results (the structural zeros of E, A, W) reach the caller. What has no scalar form here (an LU
factorization of a matrix known only at run time, a triangular solve) is a block of the array translator's
C, fed and read by nodes. The code grows with the number of scalar operations (n^3 for the Riccati
products), so that large state dimensions are better served by the array translator.
"""

from __future__ import annotations

import numpy as np

from ._primitives import (
    ctype,
)
from ._scalar_emit import ControlFlow, Emission
from ._scalar_nodes import ScalarNodes, Scope, lane_type
from ._scalar_ops import Equations, Indexing, Reductions


class ScalarTranslator(Emission, ControlFlow, Reductions, Indexing, Equations, ScalarNodes):
    """Builds the scalar graph of a jaxpr and writes it as C (one instance per generated source)."""


def structural_zero(x) -> np.ndarray:
    """Where a parameter's value ``x`` is +0, folded as a constant by a kernel of its zero pattern (a -0 is read
    at run time: folded as +0, it would change the sign of a product)."""
    x = np.asarray(x)
    return (x == 0) & ~np.signbit(x) if x.dtype.kind == "f" else x == 0


def scalar_jaxpr_to_c(name: str, closed_jaxpr, arg_names: list[str], out_names: list[str], *,
                      translator: ScalarTranslator | None = None,
                      zero_patterns: dict[str, np.ndarray] | None = None,
                      lanes: tuple[str, ...] | None = None) -> tuple[str, ScalarTranslator]:
    """A C function ``void name(const T *arg..., T *out...)`` computing ``closed_jaxpr`` on flat row-major
    arrays, as straight-line scalar code (functions in ``translator.function_texts``).

    ``zero_patterns``: for some arguments (by name), an array of their shape whose zeros (+0, not -0:
    :func:`structural_zero`) are structural: those elements are the constant +0 (folded where that is exact),
    the others are read at run time. The code then serves every value of the argument with that zero pattern
    (the engine's parameters: a new weight set is data).

    ``lanes``: the names of the arguments shared by every lane, to write the function for ``LANES`` trials at
    once (:meth:`ScalarTranslator.emit_lanes`): the others, and the outputs, are arrays of lane vectors."""
    tr = translator or ScalarTranslator()
    jaxpr = closed_jaxpr.jaxpr
    tr.scope = Scope(None)
    zero_patterns = zero_patterns or {}
    args = []
    for v, n in zip(jaxpr.invars, arg_names, strict=True):
        arr = np.empty(v.aval.shape, dtype=object)
        pattern = zero_patterns.get(n)
        for j, idx in enumerate(np.ndindex(*v.aval.shape)):
            zero = pattern is not None and structural_zero(np.asarray(pattern)[idx])
            arr[idx] = tr.const(0, v.aval.dtype, pinned=True) if zero else tr.leaf(f"{n}[{j}]", v.aval.dtype)
            if lanes is not None and n in lanes and not zero:
                tr.shared.add(arr[idx])
        args.append(arr)
    outs = tr.run(jaxpr, closed_jaxpr.consts, args)
    out_pairs = [(f"{n}[{j}]", int(x)) for n, o in zip(out_names, outs, strict=True) for j, x in enumerate(o.ravel())]
    body = tr.emit_body(out_pairs) if lanes is None else tr.emit_lanes(out_pairs)

    def typ(dtype, n):
        return ctype(dtype) if lanes is None or n in lanes else lane_type(dtype)

    sig_in = [f"const {typ(v.aval.dtype, n)} *restrict {n}" for v, n in zip(jaxpr.invars, arg_names, strict=True)]
    sig_out = [f"{typ(v.aval.dtype, n)} *restrict {n}" for v, n in zip(jaxpr.outvars, out_names, strict=True)]
    # An empty output (u_last of a system without inputs) is written by nothing: (void) it too, for -Wextra.
    empty_outs = [n for v, n in zip(jaxpr.outvars, out_names, strict=True) if v.aval.size == 0]
    used = "".join(f"    (void){n};\n" for n in [*arg_names, *empty_outs])
    text = f"static void {name}({', '.join(sig_in + sig_out)})\n{{\n{used}{body}}}\n"
    return text, tr
