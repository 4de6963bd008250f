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

import math
import struct

import numpy as np
from jax.extend import core as jcore

from .._frames import eqn_frames
from ._jaxpr_c import Translator
from ._primitives import (
    BINARY,
    BOOL_BINARY,
    BOOL_UNARY,
    CALLS,
    FLOAT_BINARY,
    FLOAT_UNARY,
    INT_BINARY,
    INT_UNARY,
    REDUCE,
    ROUND_EVEN,
    STRUCTURAL,
    UnsupportedPrimitive,
    Val,
    ctype,
    element_ids,
    fill_value,
    float_to_int,
    index_mode,
    inlined,
    int_division,
    integer_pow,
    jaxpr_size,
    literal,
    np_eval,
    own_precision,
    refuse_choice,
    saturated,
    shift_left,
    take_layout,
)

_SCALAR_FOLD = {"neg", "add", "add_any", "sub", "mul", "div", "max", "min", "sin", "cos", "sqrt", "abs",
                "exp", "log", "eq", "ne", "lt", "le", "gt", "ge", "and", "or", "not", "is_finite",
                "stop_gradient"}
_FOLDABLE = frozenset(_SCALAR_FOLD | {"sel", "convert", "ipow"})
_F64 = np.dtype(np.float64)
# float64 folds that Python's own arithmetic does exactly as NumPy's (IEEE double, round to nearest): no
# ufunc call and error-state context per folded constant (a first build folds thousands)
_SIMPLIFIED = frozenset({"mul", "add", "add_any", "sub", "div", "neg", "sel", "and", "or", "stop_gradient", "copy",
                         "copy_p", "reduce_precision", "optimization_barrier", "real", "ipow", "convert"})
"""The operations :meth:`ScalarTranslator._simplify` may rewrite (the others it leaves at once)."""


def _negative_zero(v) -> bool:
    """Whether the known value ``v`` is -0.0."""
    return v == 0 and math.copysign(1.0, float(v)) < 0


_PY_F64 = {"add": float.__add__, "add_any": float.__add__, "sub": float.__sub__, "mul": float.__mul__}


LOOKUP_MIN = 8
"""A run-time index into a constant operand over more places than this reads a C array (fewer: selects)."""
UNROLL_MAX = 20000
"""The most equations an unrolled ``scan`` (:meth:`ScalarTranslator.unrolled_scan`) may copy."""
_F64_BYTES = struct.Struct("=d").pack  # as np.float64(v).tobytes(): native order
CUMULATIVE = {"cumsum": "add", "cumprod": "mul", "cummax": "max", "cummin": "min"}


class Scope:
    """A C block: the nodes created in it, in order, and its table of common subexpressions."""

    def __init__(self, parent: Scope | None):
        self.parent = parent
        self.nodes: list[int] = []
        self.cse: dict = {}
        self.stmts: list = []  # ("node", id) | ("while", ...) | ("block", ...) in order


class ScalarTranslator:
    """Builds the scalar graph of a jaxpr and writes it as C (one instance per generated source)."""

    def __init__(self):
        self.op: list[str] = []
        self.args: list[tuple] = []
        self.dtype: list[np.dtype] = []
        self.value: list = []  # the constant's value, or the C expression of a leaf
        self.scope_of: list[Scope] = []
        self.scope = Scope(None)
        self.table_lines: list[str] = []
        self.function_texts: list[str] = []  # none: calls are inlined (the export reads it from either translator)
        self.counter = [0]
        self.lanes = False  # writing lane code (emit_lanes): every non-shared value is a vector of trials
        self.shared: set[int] = set()  # values with one value for every lane (parameters, times, and from them)
        self.active: str | None = None  # in lane code inside a cond's arm: the C mask of the lanes that take it
        self.const_arrays: dict = {}  # constant arrays by dtype, shape and bytes (their nodes live in the root scope)
        self.lookups: dict = {}  # constant operands read at run-time indices: their C arrays, by node ids
        self.pinned: set[int] = set()  # constants from a parameter's zero pattern, and those folded from them
        self.within: list = []  # the equations being translated, outermost first (a call's, then its body's)
        self.never_neg0: dict[int, bool] = {}  # memo of _never_negative_zero
        self.preds: dict = {}  # id of an array of node ids -> (the array, the booleans it converts: _note_pred)

    def fresh(self, prefix: str) -> str:
        self.counter[0] += 1
        return f"{prefix}{self.counter[0]}"

    # --- nodes ----------------------------------------------------------------------------------------------
    def _new(self, op, args, dtype, value=None) -> int:
        i = len(self.op)
        self.op.append(op)
        self.args.append(args)
        self.dtype.append(dtype if type(dtype) is np.dtype else np.dtype(dtype))
        self.value.append(value)
        self.scope_of.append(self.scope)
        if op not in ("const", "leaf"):
            self.scope.stmts.append(("node", i))
        return i

    def const(self, value, dtype, pinned: bool = False) -> int:
        """The node of a known value. ``pinned``: known only because the code is specialized to a parameter's
        zero pattern (:func:`scalar_jaxpr_to_c`), a run-time value to XLA (kept apart from true constants:
        :meth:`_zero_array`)."""
        dt = dtype if type(dtype) is np.dtype else np.dtype(dtype)
        if type(value) is float and dt is _F64:  # the common case, without a NumPy round trip
            v = value
            key = ("const", _F64.str, _F64_BYTES(v), pinned)
        else:
            v = np.asarray(value, dt).item()
            key = ("const", dt.str, repr(v) if dt.kind != "f" else np.float64(v).tobytes(), pinned)
        s = self.scope
        while s.parent is not None:
            s = s.parent
        got = s.cse.get(key)
        if got is None:
            saved, self.scope = self.scope, s
            got = s.cse[key] = self._new("const", (), dt, v)
            self.scope = saved
            if pinned:
                self.pinned.add(got)
        return got

    def leaf(self, expr: str, dtype) -> int:
        return self._new("leaf", (), dtype, expr)

    def is_const(self, i: int) -> bool:
        return self.op[i] == "const"

    def cval(self, i: int):
        return self.value[i]

    def node(self, op: str, args: tuple, dtype, param=None) -> int:
        """A node ``op(args)`` after folding, simplification and lookup of an equal node in scope."""
        dt = dtype if type(dtype) is np.dtype else np.dtype(dtype)
        if op in _FOLDABLE:
            ops = self.op
            for a in args:
                if ops[a] != "const":
                    break
            else:
                folded = self._fold(op, args, dt, param)
                if folded is not None:
                    return self.const(folded, dt, pinned=not self.pinned.isdisjoint(args))
        simple = self._simplify(op, args, dt, param)
        if simple is not None:
            return simple
        key = (op, args, dt.str, param)
        s = self.scope
        while s is not None:
            if key in s.cse:
                return s.cse[key]
            s = s.parent
        i = self._new(op, args, dt, param)
        self.scope.cse[key] = i
        return i

    def _fold(self, op, args, dt, param):
        if dt is _F64 and op in _PY_F64 and all(self.dtype[a] is _F64 for a in args):
            v = self.value
            return _PY_F64[op](float(v[args[0]]), float(v[args[1]]))
        xs = [np.asarray(self.cval(a), self.dtype[a]) for a in args]
        with np.errstate(all="ignore"):
            if op == "sel":
                return xs[1] if bool(xs[0]) else xs[2]
            if op == "convert":
                return saturated(xs[0], dt) if dt.kind in "iu" and xs[0].dtype.kind == "f" else xs[0].astype(dt)
            if op == "ipow":  # XLA's products (NumPy's power of a float may differ in the last bit)
                return integer_pow(xs[0], param) if xs[0].dtype.kind == "f" or param >= 0 else None
            out = np_eval(op, {}, xs, [dt])
            return None if out is None else out[0]

    def _simplify(self, op, a, dt, param):
        """A node equal to ``op(a)`` for every value of the operands, bit for bit (IEEE 754: NaN, infinities and
        the sign of zero included), or None. ``x * 1``, ``x * -1 = -x``, ``x / 1``, ``x - (+0)``, ``x + (-0)``
        and ``(-0) - x = -x`` are exact, and ``x + (+0)`` where x is never -0 (:meth:`_never_negative_zero`);
        ``0 * x`` is not (NaN for an infinite or NaN x, -0 for a negative one), nor ``x + (+0)`` of any x (+0
        for x = -0), ``(+0) - x`` or ``0 / x``: those are computed. (XLA's own rule
        ``x + 0 = x`` for a whole array of known zeros is :meth:`_zero_array`'s.) Integers fold ``0 * x`` and
        ``x + 0``, exact for them."""
        if op not in _SIMPLIFIED:
            return None
        ops, values = self.op, self.value
        c = [ops[x] == "const" for x in a]
        v = [values[x] if k else None for x, k in zip(a, c, strict=True)]
        real = dt.kind == "f"
        if op == "mul":
            for k in (0, 1):
                if c[k] and v[k] == 0 and not real and dt != np.bool_:
                    return self.const(0, dt)
                if c[k] and v[k] == 1:
                    return a[1 - k]
                if c[k] and v[k] == -1 and real:
                    return self.node("neg", (a[1 - k],), dt)
            if a[0] > a[1]:
                return self.node("mul", (a[1], a[0]), dt)
        elif op in ("add", "add_any"):
            for k in (0, 1):
                if c[k] and v[k] == 0 and (not real or _negative_zero(v[k]) or self._never_negative_zero(a[1 - k])):
                    return a[1 - k]
            if op == "add_any" or a[0] > a[1]:
                return self.node("add", tuple(sorted(a)), dt)
        elif op == "sub":
            if c[1] and v[1] == 0 and not (real and _negative_zero(v[1])):
                return a[0]
            if c[0] and v[0] == 0 and real and _negative_zero(v[0]):
                return self.node("neg", (a[1],), dt)
            if a[0] == a[1] and not real:
                return self.const(0, dt)
        elif op == "div":
            if c[1] and v[1] == 1:
                return a[0]
        elif op == "neg":
            if self.op[a[0]] == "neg":
                return self.args[a[0]][0]
        elif op == "sel":
            if c[0]:
                return a[1] if v[0] else a[2]
            if a[1] == a[2]:
                return a[1]
        elif op == "and" and dt == np.bool_:
            for k in (0, 1):
                if c[k]:
                    return a[1 - k] if v[k] else self.const(False, dt)
        elif op == "or" and dt == np.bool_:
            for k in (0, 1):
                if c[k]:
                    return self.const(True, dt) if v[k] else a[1 - k]
        elif op in ("stop_gradient", "copy", "copy_p", "reduce_precision", "optimization_barrier", "real"):
            return a[0]
        elif op == "ipow":
            if param == 0:  # XLA's x ** 0 is 1 for every x, NaN included
                return self.const(1, dt)
            if param == 1:
                return a[0]
            if param == 2:
                return self.node("mul", (a[0], a[0]), dt)
        elif op == "convert" and self.dtype[a[0]] == dt:
            return a[0]
        return None

    def _behind_barrier(self, x: np.ndarray) -> np.ndarray:
        """``x`` as XLA sees it behind an optimization barrier: the same values, but its known elements are
        run-time values to XLA (pinned: :meth:`_zero_array`) and the array is no converted boolean
        (:meth:`_note_pred`): a new array."""
        out = np.empty(x.shape, dtype=object)
        for idx in np.ndindex(*x.shape):
            i = x[idx]
            out[idx] = self.const(self.value[i], self.dtype[i], pinned=True) if self.op[i] == "const" else i
        return out

    def _zero_array(self, x: np.ndarray) -> bool:
        """Whether ``x`` is a whole operand of known zeros (+0 or -0) that XLA sees as a constant: its algebraic
        simplifier makes ``x + 0`` and ``x - 0`` ``x`` (keeping a -0 that IEEE addition of +0 turns into +0).
        Not for zeros pinned by a parameter's zero pattern, which XLA reads at run time and adds."""
        ops, values, pinned = self.op, self.value, self.pinned
        for i in x.ravel().tolist():
            if ops[i] != "const" or values[i] != 0 or i in pinned:
                return False
        return True

    def array(self, v: np.ndarray, dtype) -> np.ndarray:
        return np.asarray(v, dtype=object)

    def const_array(self, value, dtype, pinned: bool = False) -> np.ndarray:
        value = np.asarray(value, dtype)
        key = (value.dtype.str, value.shape, value.tobytes(), pinned)  # a literal recurs in every equation's copy
        if key not in self.const_arrays:
            out = np.empty(value.shape, dtype=object)
            for idx in np.ndindex(*value.shape):
                out[idx] = self.const(value[idx], dtype, pinned)
            self.const_arrays[key] = out
        return self.const_arrays[key].copy()

    # --- expressions ----------------------------------------------------------------------------------------
    def expr(self, i: int) -> str:
        """The C expression naming node ``i`` (a literal, a leaf's expression, or its local)."""
        op = self.op[i]
        if op == "const":
            return literal(self.value[i], self.dtype[i])
        name = self.value[i] if op == "leaf" else f"n{i}"
        return f"{name}[l]" if self.lanes and i not in self.shared else name

    def rhs(self, i: int, sub: dict[int, str] | None = None) -> str:
        """The C expression computing node ``i`` from its operands (``sub``: C expressions to read for some of
        them instead of their names)."""
        op, a, dt = self.op[i], self.args[i], self.dtype[i]
        e = [self.expr(x) if sub is None or x not in sub else sub[x] for x in a]
        if op == "sel":
            return f"({e[0]}) ? ({e[1]}) : ({e[2]})"
        if op == "convert":
            if dt.kind in "iu" and self.dtype[a[0]].kind == "f":
                return float_to_int(e[0], dt)
            return f"({e[0]}) != 0" if dt == np.bool_ else f"({ctype(dt)})({e[0]})"
        if op == "ipow":
            p = self.value[i]
            prod = " * ".join([f"({e[0]})"] * abs(p)) if p else "1"
            return f"1.0 / ({prod})" if p < 0 else prod
        if op == "ref":
            return self.value[i]
        if op == "lookup":
            table, off = self.value[i]
            return f"{table}[{e[0]} + {off}]"
        kind = self.dtype[a[0]].kind
        if kind in "iu" and op in ("div", "rem"):
            return int_division(op, e[0], e[1], self.dtype[a[0]])
        if kind in "iu" and op == "shift_left":
            return shift_left(e[0], e[1], self.dtype[a[0]])
        table = {"f": {**FLOAT_UNARY, **BINARY, **FLOAT_BINARY, **ROUND_EVEN},
                 "b": {**BOOL_UNARY, **BINARY, **BOOL_BINARY}}.get(kind, {**INT_UNARY, **BINARY, **INT_BINARY})
        if op not in table:
            raise UnsupportedPrimitive(f"primitive {op!r} on {self.dtype[a[0]]}")
        return table[op].format(a=e[0], b=e[1] if len(e) > 1 else "")

    # --- a jaxpr --------------------------------------------------------------------------------------------
    def run(self, jaxpr, consts, args: list[np.ndarray]) -> list[np.ndarray]:
        """The outputs of ``jaxpr`` (with ``consts``) on ``args``, arrays of node ids."""
        env: dict = {}

        def read(a):
            if isinstance(a, jcore.Literal):
                return self.const_array(np.asarray(a.val, a.aval.dtype), a.aval.dtype)
            return env[a]

        for var, c in zip(jaxpr.constvars, consts, strict=True):
            env[var] = self.const_array(np.asarray(c), var.aval.dtype)
        for var, a in zip(jaxpr.invars, args, strict=True):
            env[var] = a
        for eqn in jaxpr.eqns:
            ins = [read(a) for a in eqn.invars]
            self.within.append(eqn)
            try:
                outs = self.equation(eqn, ins)
            except UnsupportedPrimitive as e:
                e.frames.extend(eqn_frames(eqn))
                raise
            finally:
                self.within.pop()
            for var, o in zip(eqn.outvars, outs, strict=True):
                env[var] = np.asarray(o, dtype=object).reshape(var.aval.shape)
            self._note_pred(eqn, ins, env)
        return [read(a) for a in jaxpr.outvars]

    _SAME = frozenset({"convert_element_type", "split", "copy", "copy_p", "reduce_precision"})

    def _note_pred(self, eqn, ins, env) -> None:
        """Remember an array that is a boolean array converted to floats (``jacfwd``'s one-hot basis, a user's
        ``mask.astype(float)``), as XLA sees it: through the equations it drops as no-ops (a convert to the
        same type, a split in one piece) and through reshapes and transposes, which XLA moves past a product
        with a scalar (not through a broadcast or a slice, nor a convert from another float type: there XLA
        multiplies). XLA's algebraic simplifier makes a product with one a select: :meth:`_masked`."""
        name, out = eqn.primitive.name, eqn.outvars
        if len(out) != 1 or not ins or np.dtype(out[0].aval.dtype).kind != "f":
            return
        src = eqn.invars[0].aval
        moved = False
        if name == "convert_element_type" and np.dtype(src.dtype) == np.bool_:
            pred = ins[0]
        elif name in self._SAME and tuple(src.shape) == tuple(out[0].aval.shape) and src.dtype == out[0].aval.dtype \
                or name in ("reshape", "squeeze", "expand_dims", "transpose"):
            held = self.preds.get(id(ins[0]))
            if held is None or held[0] is not ins[0]:
                return
            pred = np.transpose(held[1], eqn.params["permutation"]) if name == "transpose" else \
                held[1].reshape(out[0].aval.shape)
            moved = held[2] or name not in self._SAME
        else:
            return
        arr = env[out[0]]
        self.preds[id(arr)] = (arr, pred, moved)  # the array itself is held: its id is not reused meanwhile

    def _masked(self, ins, shape, dtype):
        """XLA's ``x * convert(p) = select(p, x, 0)`` (its algebraic simplifier's, where the factor is a boolean
        array converted to floats: :meth:`_note_pred`): x where p holds, else +0, also for a NaN or infinite x
        and a negative one (IEEE's product: NaN, -0). None where neither factor is one."""
        for k in (0, 1):
            held = self.preds.get(id(ins[k]))
            if held is not None and held[0] is ins[k]:
                if held[2] and len(set(ins[1 - k].ravel().tolist())) > 1:
                    continue  # reshaped or transposed: XLA moves that past the product only by a scalar
                zero = self.const(0.0, dtype)
                f = np.frompyfunc(lambda p, x, zero=zero: self.node("sel", (p, x, zero), dtype), 2, 1)
                out = np.asarray(f(held[1], ins[1 - k]), dtype=object)
                return np.broadcast_to(out, shape).copy() if out.shape != tuple(shape) else out
        return None

    def _known(self, x: np.ndarray) -> bool:
        ops = self.op
        for i in x.ravel().tolist():
            if ops[i] != "const":
                return False
        return True

    def _values(self, x: np.ndarray, dtype) -> np.ndarray:
        return np.array(list(map(self.value.__getitem__, x.ravel().tolist())), dtype=dtype).reshape(x.shape)

    def equation(self, eqn, ins: list[np.ndarray]) -> list[np.ndarray]:
        name, params = eqn.primitive.name, eqn.params
        odt = [np.dtype(v.aval.dtype) for v in eqn.outvars]
        oshape = [tuple(v.aval.shape) for v in eqn.outvars]
        idt = [np.dtype(v.aval.dtype) for v in eqn.invars]
        if name in CALLS or name == "custom_linear_solve":
            # inlined: a call's constants fold into it, and the zeros of its results reach the caller
            if name in ("checkpoint", "remat", "remat2") and params.get("differentiated", False):
                # JAX lowers a differentiated checkpoint with an optimization barrier on the inputs it keeps
                # from common subexpressions (prevent_cse, one flag or one per input)
                keep = params.get("prevent_cse", True)
                keep = (keep,) * len(ins) if isinstance(keep, bool) else tuple(keep)
                ins = [self._behind_barrier(x) if k else x for x, k in zip(ins, keep, strict=True)]
            return self.run(*inlined(name, params, ins))
        if name == "while":
            return self.while_loop(params, ins)
        if name == "cond":
            return self.cond(params, ins)
        if name == "scan":
            return self.scan(params, ins)
        if name == "optimization_barrier":
            return [self._behind_barrier(x) for x in ins]
        if name == "reduce_precision":
            own_precision(params, idt[0])
        if all(self._known(x) for x in ins):
            xs = [self._values(x, d) for x, d in zip(ins, idt, strict=True)]
            outs = np_eval(name, params, xs, odt)
            if outs is None:
                import jax
                with jax.ensure_compile_time_eval():
                    outs = eqn.primitive.bind(*xs, **params)
                outs = outs if eqn.primitive.multiple_results else [outs]
            pinned = any(not self.pinned.isdisjoint(x.ravel().tolist()) for x in ins)
            return [self.const_array(np.asarray(o), d, pinned) for o, d in zip(outs, odt, strict=True)]
        if name == "gather" and not self._known(ins[1]):
            if index_mode(params) != "fill":
                try:
                    return [self.take(ins[0], ins[1], params, oshape[0], odt[0])]
                except UnsupportedPrimitive:
                    pass
            return [self.gather(ins[0], ins[1], params, oshape[0], odt[0])]
        if name in ("scatter", "scatter-add", "scatter_add") and (
                not self._known(ins[1]) or (name != "scatter" and not params.get("unique_indices", False))):
            # run-time indices, or known ones that may repeat (their updates add up: the selects fold)
            return [self.scatter(ins[0], ins[1], ins[2], params, name != "scatter", odt[0])]
        if name == "dynamic_slice" and not all(self._known(x) for x in ins[1:]):
            return [self.dynamic_slice(ins[0], ins[1:], params["slice_sizes"], oshape[0], odt[0])]
        if name == "dynamic_update_slice" and not all(self._known(x) for x in ins[2:]):
            return [self.dynamic_update_slice(ins[0], ins[1], ins[2:], odt[0])]
        if name in STRUCTURAL:
            return self.structural(eqn, ins, idt, oshape)
        if name in REDUCE:
            return [self.reduce(REDUCE[name], ins[0], params["axes"], oshape[0], odt[0])]
        if name == "sort":
            return self.sort(ins, int(params["dimension"]), int(params["num_keys"]), idt)
        if name in CUMULATIVE:
            return [self.cumulative(CUMULATIVE[name], ins[0], int(params["axis"]), bool(params["reverse"]), odt[0])]
        if name == "round":
            op = "rint" if int(params.get("rounding_method", 0)) == 1 else "round"
            return [self.map1(lambda x: self.node(op, (x,), odt[0]), ins[0], oshape[0])]
        if name == "cholesky":
            return [self.cholesky(ins[0], odt[0])]
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], params["dimension_numbers"], oshape[0], odt[0])]
        if name in ("lu", "lu_pivots_to_permutation", "triangular_solve", "eigh"):
            if name == "eigh":
                refuse_choice(eqn, self.within[:-1])
            return self.block(eqn, ins, idt)
        if name == "integer_pow":
            return [self.map1(lambda x: self.node("ipow", (x,), odt[0], params["y"]), ins[0], oshape[0])]
        if name == "convert_element_type":
            return [self.map1(lambda x: self.node("convert", (x,), odt[0]), ins[0], oshape[0])]
        if name == "select_n":
            return [self.select_n(ins, oshape[0], odt[0])]
        if name == "clamp":
            lo, x, hi = (np.broadcast_to(v, oshape[0]) for v in ins)
            f = np.frompyfunc(lambda a, b, c: self.node("min", (self.node("max", (b, a), odt[0]), c), odt[0]), 3, 1)
            return [f(lo, x, hi)]
        if name == "mul" and odt[0].kind == "f":
            masked = self._masked(ins, oshape[0], odt[0])
            if masked is not None:
                return [masked]
        if name in ("add", "add_any", "sub") and odt[0].kind == "f":
            # XLA's algebraic simplifier: x + 0 and x - 0 are x for a whole operand of zeros it knows
            if self._zero_array(ins[1]):
                return [np.broadcast_to(ins[0], oshape[0]).copy()]
            if name != "sub" and self._zero_array(ins[0]):
                return [np.broadcast_to(ins[1], oshape[0]).copy()]
        if name in FLOAT_UNARY or name in INT_UNARY or name in BOOL_UNARY or name in BINARY \
                or name in FLOAT_BINARY or name in INT_BINARY or name in BOOL_BINARY:
            f = np.frompyfunc(lambda *a: self.node(name, tuple(a), odt[0]), len(ins), 1)
            out = np.asarray(f(*ins), dtype=object)  # frompyfunc broadcasts a scalar operand itself
            return [np.broadcast_to(out, oshape[0]).copy() if out.shape != oshape[0] else out]
        raise UnsupportedPrimitive(f"primitive {name!r} has no C translation (supported: liemef.codegen.PRIMITIVES)")

    def map1(self, f, x, shape):
        out = np.empty(x.shape, dtype=object)
        for idx in np.ndindex(*x.shape):
            out[idx] = f(x[idx])
        return out.reshape(shape)

    def select_n(self, ins, shape, dtype):
        pred, cases = np.broadcast_to(ins[0], shape), [np.broadcast_to(c, shape) for c in ins[1:]]
        out = np.empty(shape, dtype=object)
        pdt = self.dtype[pred.ravel()[0]] if pred.size else np.dtype(bool)
        for idx in np.ndindex(*shape):
            p = pred[idx]
            if pdt == np.bool_ and len(cases) == 2:
                out[idx] = self.node("sel", (p, cases[1][idx], cases[0][idx]), dtype)
            else:
                acc = cases[-1][idx]
                for j in range(len(cases) - 2, -1, -1):
                    acc = self.node("sel", (self.node("eq", (p, self.const(j, pdt)), np.bool_), cases[j][idx], acc),
                                    dtype)
                out[idx] = acc
        return out

    # --- data movement --------------------------------------------------------------------------------------
    def structural(self, eqn, ins, idt, oshape):
        known = [Val(tuple(x.shape), d, const=self._values(x, d) if self._known(x) else None)
                 for x, d in zip(ins, idt, strict=True)]
        data, bases, outs, add_into = element_ids(eqn, known)
        flat = {j: ins[j].ravel() for j in data}

        def node_of(idv, dtype):
            if idv == 0:
                return self.const(0, dtype)
            for j in data:
                if bases[j] <= idv < bases[j] + flat[j].size:
                    return flat[j][idv - bases[j]]
            raise AssertionError(idv)

        results = []
        for ids, shape, v in zip(outs, oshape, eqn.outvars, strict=True):
            dt = np.dtype(v.aval.dtype)
            if add_into:
                res = ins[0].ravel().copy()
                upd = flat[2]
                for i, idv in enumerate(ids):
                    if bases[2] <= idv < bases[2] + upd.size:
                        res[i] = self.node("add", (res[i], upd[idv - bases[2]]), dt)
                results.append(res.reshape(shape))
            else:
                results.append(np.array([node_of(int(i), dt) for i in ids], dtype=object).reshape(shape))
        return results

    def gather_by_cases(self, eqn, ins, idt, shape, dtype):
        """Any gather whose run-time index picks along one operand axis (``start_index_map`` of length 1, e.g.
        the pivoting of ``linalg.solve`` batched by ``jacfwd``): the gather is moved on element ids once per
        possible index value, and each output element is a chain of selects on its (clamped) index."""
        x, idx = ins[0], ins[1]
        dn = eqn.params["dimension_numbers"]
        smap = tuple(int(v) for v in dn.start_index_map)
        if len(smap) != 1 or idx.shape[-1:] != (1,):
            raise UnsupportedPrimitive(f"gather with indices known only at run time along more than one axis ({dn})")
        a = smap[0]
        positions = x.shape[a] - int(eqn.params["slice_sizes"][a]) + 1
        batch_pos = [k for k in range(len(shape)) if k not in tuple(int(v) for v in dn.offset_dims)]
        flat = x.ravel()
        cases = []
        for v in range(positions):
            known = [Val(tuple(x.shape), idt[0]), Val(tuple(idx.shape), idt[1], const=np.full(idx.shape, v, idt[1]))]
            _, bases, outs, _ = element_ids(eqn, known)
            cases.append(outs[0].ravel())
        out = np.empty(int(np.prod(shape, dtype=np.int64)), dtype=object)
        for o, oi in enumerate(np.ndindex(*shape)):
            r = idx[tuple(oi[k] for k in batch_pos) + (0,)]
            acc = None
            for v in range(positions - 1, -1, -1):
                i = int(cases[v][o])
                cand = self.const(0, dtype) if i == 0 else flat[i - bases[0]]
                # clamped, as XLA's gather: below 0 reads position 0, above the last the last
                acc = cand if acc is None else self.node("sel", (self.node("le", (r, self.const(v, idt[1])), np.bool_),
                                                                 cand, acc), dtype)
            out[o] = acc
        return out.reshape(shape)

    # --- indices known only at run time: gathers, scatters and dynamic slices of any form ---------------------
    def _start(self, starts, op_shape, sizes, clip: bool):
        """One window's place in an operand: ``starts`` maps operand axes to the (run-time) start index nodes,
        ``sizes`` is the window's size per axis. Returns the node of the flat offset of the window's first
        element (starts clamped into range, as XLA does), the values that offset can take, and the node
        saying whether the unclamped starts are in range (None where ``clip``: no test is needed)."""
        strides = np.cumprod((1,) + tuple(op_shape)[::-1])[::-1][1:]
        base, values, inb = None, [0], None
        for d, s in starts.items():
            hi = int(op_shape[d]) - int(sizes[d])
            if hi < 0:
                raise UnsupportedPrimitive(f"a window of {sizes[d]} on an axis of {op_shape[d]}")
            dt = self.dtype[s]
            signed = dt.kind != "u"  # an unsigned index is never below 0 (and a test of it a C warning)
            c = self.node("min", (self.node("max", (s, self.const(0, dt)), dt) if signed else s, self.const(hi, dt)),
                          dt)
            if not clip:
                ok = self.node("le", (s, self.const(hi, dt)), np.bool_)
                if signed:
                    ok = self.node("and", (self.node("ge", (s, self.const(0, dt)), np.bool_), ok), np.bool_)
                inb = ok if inb is None else self.node("and", (inb, ok), np.bool_)
            term = self.node("mul", (self.node("convert", (c,), np.int32), self.const(int(strides[d]), np.int32)),
                             np.int32)
            base = term if base is None else self.node("add", (base, term), np.int32)
            vals = [int(self.cval(c))] if self.is_const(c) else range(hi + 1)
            values = sorted({v + k * int(strides[d]) for v in values for k in vals})
            if len(values) > 4096:
                raise UnsupportedPrimitive(f"a run-time index over more than 4096 places of an operand {op_shape}")
        return (self.const(0, np.int32) if base is None else base), values, inb

    def _pick(self, flat, base, values, off: int, dtype):
        """``flat[base + off]`` for a run-time ``base`` among ``values``: a chain of selects, or, from a
        constant operand (a user's table) over more than :data:`LOOKUP_MIN` places, a read of a
        ``static const`` C array at the run-time index."""
        if len(values) > LOOKUP_MIN and all(self.is_const(n) for n in flat):
            key = tuple(int(n) for n in flat)
            if key not in self.lookups:
                name = self.fresh("tab")
                body = ", ".join(literal(self.cval(n), dtype) for n in flat)
                self.table_lines.append(f"static const {ctype(dtype)} {name}[{len(flat)}] = {{{body}}};")
                self.lookups[key] = name
            return self.node("lookup", (base,), dtype, (self.lookups[key], off))
        acc = None
        for v in reversed(values):
            cand = flat[v + off]
            acc = cand if acc is None else self.node(
                "sel", (self.node("le", (base, self.const(v, np.int32)), np.bool_), cand, acc), dtype)
        return acc

    @staticmethod
    def _windows(shape, window_pos, op_dims, op_shape):
        """For each element of a gather's output (a scatter's updates), row-major: its batch multi-index (the
        positions not in ``window_pos``) and its flat offset in the operand within the window (``op_dims``:
        the operand axis of each window position)."""
        strides = np.cumprod((1,) + tuple(op_shape)[::-1])[::-1][1:]
        batch_pos = [k for k in range(len(shape)) if k not in window_pos]
        out = []
        for e in np.ndindex(*shape):
            off = sum(int(e[p]) * int(strides[d]) for p, d in zip(window_pos, op_dims, strict=True))
            out.append((tuple(e[k] for k in batch_pos), off))
        return out

    def _batching(self, op_dims, idx_dims, idx_dtype):
        """For a batch multi-index of the indices, the (known) starts on the operand's batching axes: an
        operand batching axis is indexed by the position along its paired index batch axis
        (``take_along_axis``)."""
        dt = np.int32
        return lambda b: {int(d): self.const(int(b[int(j)]), dt) for d, j in zip(op_dims, idx_dims, strict=True)}

    def gather(self, x, idx, params, shape, dtype):
        """Any gather with indices known only at run time (``x[i]``, ``jnp.take``, ``take_along_axis``, an
        interpolation's bracket, the permutations of a sort's or an LU's derivative), clamped into range or
        filled (``mode``) as XLA does: each output element is a chain of selects over the places its window
        can start."""
        dn = params["dimension_numbers"]
        sizes = tuple(int(v) for v in params["slice_sizes"])
        smap = tuple(int(v) for v in dn.start_index_map)
        collapsed = tuple(int(v) for v in dn.collapsed_slice_dims) + tuple(int(v) for v in dn.operand_batching_dims)
        op_dims = [d for d in range(x.ndim) if d not in collapsed]
        paired = self._batching(dn.operand_batching_dims, dn.start_indices_batching_dims, idx.dtype)
        mode = index_mode(params)
        fill = params.get("fill_value")
        if mode == "fill":
            fill = fill_value(fill, dtype)
        flat = x.ravel()
        starts = {}
        out = np.empty(int(np.prod(shape, dtype=np.int64)), dtype=object)
        for o, (b, off) in enumerate(self._windows(shape, tuple(int(v) for v in dn.offset_dims), op_dims, x.shape)):
            if b not in starts:
                starts[b] = self._start({**paired(b), **{d: idx[b + (k,)] for k, d in enumerate(smap)}}, x.shape,
                                        sizes, clip=mode != "fill")
            base, values, inb = starts[b]
            val = self._pick(flat, base, values, off, dtype)
            out[o] = val if inb is None else self.node("sel", (inb, val, self.const(fill, dtype)), dtype)
        return out.reshape(shape)

    def scatter(self, x, idx, upd, params, add: bool, dtype):
        """A scatter (or scatter-add) with indices known only at run time: each update lands where its window
        starts (clamped, or dropped when out of range, ``mode``, as XLA does); updates in order, the last
        write winning."""
        dn = params["dimension_numbers"]
        wpos = tuple(int(v) for v in dn.update_window_dims)
        inserted = tuple(int(v) for v in dn.inserted_window_dims) + tuple(int(v) for v in dn.operand_batching_dims)
        paired = self._batching(dn.operand_batching_dims, dn.scatter_indices_batching_dims, idx.dtype)
        op_dims = [d for d in range(x.ndim) if d not in inserted]
        sizes = [1] * x.ndim
        for p, d in zip(wpos, op_dims, strict=True):
            sizes[d] = upd.shape[p]
        smap = tuple(int(v) for v in dn.scatter_dims_to_operand_dims)
        clip = index_mode(params) == "clip"
        out = x.ravel().copy()
        ups = upd.ravel()
        starts = {}
        for u, (b, off) in enumerate(self._windows(upd.shape, wpos, op_dims, x.shape)):
            if b not in starts:
                starts[b] = self._start({**paired(b), **{d: idx[b + (k,)] for k, d in enumerate(smap)}}, x.shape,
                                        sizes, clip=clip)
            base, values, inb = starts[b]
            for v in values:
                hit = self.node("eq", (base, self.const(v, np.int32)), np.bool_)
                if inb is not None:
                    hit = self.node("and", (hit, inb), np.bool_)
                p = v + off
                if add:  # a missed place keeps its element (adding 0 would make a -0 +0)
                    out[p] = self.node("sel", (hit, self.node("add", (out[p], ups[u]), dtype), out[p]), dtype)
                else:
                    out[p] = self.node("sel", (hit, ups[u], out[p]), dtype)
        return out.reshape(x.shape)

    def dynamic_slice(self, x, starts, sizes, shape, dtype):
        """``lax.dynamic_slice`` at run-time starts (clamped so that the window fits, as XLA does)."""
        base, values, _ = self._start({d: s.ravel()[0] for d, s in enumerate(starts)}, x.shape, sizes, clip=True)
        flat = x.ravel()
        wins = self._windows(shape, tuple(range(x.ndim)), tuple(range(x.ndim)), x.shape)
        return np.array([self._pick(flat, base, values, off, dtype) for _, off in wins],
                        dtype=object).reshape(shape)

    def dynamic_update_slice(self, x, upd, starts, dtype):
        """``lax.dynamic_update_slice`` at run-time starts (clamped so that the update fits, as XLA does)."""
        base, values, _ = self._start({d: s.ravel()[0] for d, s in enumerate(starts)}, x.shape, upd.shape,
                                      clip=True)
        out = x.ravel().copy()
        ups = upd.ravel()
        for u, (_, off) in enumerate(self._windows(upd.shape, tuple(range(x.ndim)), tuple(range(x.ndim)), x.shape)):
            for v in values:
                hit = self.node("eq", (base, self.const(v, np.int32)), np.bool_)
                out[v + off] = self.node("sel", (hit, ups[u], out[v + off]), dtype)
        return out.reshape(x.shape)

    def take(self, x, idx, params, shape, dtype):
        """A gather along one axis with indices known at run time (:func:`take_layout`): a chain of selects on
        the (clamped) index."""
        a, places = take_layout(params, x.shape, idx.shape, shape)
        out = np.empty(int(np.prod(shape, dtype=np.int64)), dtype=object)
        idt = self.dtype[idx.ravel()[0]]
        for o, (base, b) in enumerate(places):
            src = list(base)
            r = idx[b + (0,)]
            acc = None
            for j in range(x.shape[a] - 1, -1, -1):
                src[a] = j
                cand = x[tuple(src)]
                if acc is None:
                    acc = cand
                else:  # clamped: below 0 reads row 0, above the last reads the last
                    test = self.node("le", (r, self.const(j, idt)), np.bool_)
                    acc = self.node("sel", (test, cand, acc), dtype)
            out[o] = acc
        return out.reshape(shape)

    # --- sums -----------------------------------------------------------------------------------------------
    def total(self, terms, dtype, op="sum", xla=False):
        """The sum (or product, max, ...) of node ids, pairwise: a tree, not a chain, so that the additions do not
        wait on each other (and the rounding error grows as log n). Known zeros of a float sum are skipped only
        where that is exact: -0 always; +0 where the sum is ``xla``'s, which starts from +0 (a ``reduce_sum`` or
        ``dot_general`` over two terms or more: its result is never -0, so a -0 is made +0 by adding +0,
        unless a known term that is not 0 already rules out -0)."""
        name = {"sum": "add", "prod": "mul", "max": "max", "min": "min", "and": "and", "or": "or"}[op]
        real = np.dtype(dtype).kind == "f"
        init = op == "sum" and real and xla and len(terms) >= 2
        dropped = False
        if op == "sum":
            kept = []
            for t in terms:
                if self.is_const(t) and self.cval(t) == 0 and (not real or init or _negative_zero(self.cval(t))):
                    dropped = True
                    continue
                kept.append(t)
            terms = kept
            # a sum is -0 only if every term is: one term that never is (x * x, exp(x), a known 1) rules it out
            init = init and not any(self._never_negative_zero(t) for t in terms)
        if not terms:
            first = {"sum": 0, "prod": 1, "and": True, "or": False, "max": -np.inf, "min": np.inf}[op]
            if dropped and real and not init:  # only -0 terms were skipped: their sum is -0
                first = -0.0
            return self.const(first, dtype)
        while len(terms) > 1:
            pairs = [self.node(name, (terms[k], terms[k + 1]), dtype) for k in range(0, len(terms) - 1, 2)]
            terms = pairs + ([terms[-1]] if len(terms) % 2 else [])
        return self.node("add", (terms[0], self.const(0.0, dtype)), dtype) if init else terms[0]

    _NEVER_NEGATIVE_ZERO = frozenset({"exp", "exp2", "cos", "cosh", "abs", "is_finite", "logistic", "erfc"})

    def _never_negative_zero(self, i: int, depth: int = 0) -> bool:
        """Whether node ``i`` is never -0, whatever the inputs (a NaN is not -0): a known value other than -0,
        a square, exp, cos, abs, an integer converted, a sum with such a term, a select of two such."""
        got = self.never_neg0.get(i)
        if got is not None:
            return got
        op, a = self.op[i], self.args[i]
        if op == "const":
            out = not _negative_zero(self.value[i]) if self.dtype[i].kind == "f" else True
        elif op in self._NEVER_NEGATIVE_ZERO or (op == "mul" and a[0] == a[1]) \
                or (op == "ipow" and self.value[i] % 2 == 0):
            out = True
        elif depth > 12 or op not in ("add", "sub", "sel", "convert", "sqrt"):
            out = False
        elif op == "add":
            out = self._never_negative_zero(a[0], depth + 1) or self._never_negative_zero(a[1], depth + 1)
        elif op == "sel":
            out = self._never_negative_zero(a[1], depth + 1) and self._never_negative_zero(a[2], depth + 1)
        elif op == "convert":
            out = self.dtype[a[0]].kind != "f" or self._never_negative_zero(a[0], depth + 1)
        else:  # a - b is -0 only for a = -0 (and b = +0); sqrt(-0) is -0
            out = self._never_negative_zero(a[0], depth + 1)
        if depth <= 12:
            self.never_neg0[i] = out
        return out

    def reduce(self, op, x, axes, shape, dtype):
        axes = tuple(int(a) for a in axes)
        if op in ("argmax", "argmin"):
            return self.argbest(op, x, axes, shape, dtype)
        keep = [d for d in range(x.ndim) if d not in axes]
        n_out = int(np.prod(shape, dtype=np.int64))
        rows = x.transpose(keep + list(axes)).reshape(n_out, -1)
        return np.array([self.total(list(r), dtype, op, xla=True) for r in rows], dtype=object).reshape(shape)

    def argbest(self, op, x, axes, shape, dtype):
        """``argmax``/``argmin`` along one axis, as XLA: the first index of the largest (smallest) value, a NaN
        counting as larger (smaller) than any number (the first NaN wins)."""
        (ax,) = axes
        keep = [d for d in range(x.ndim) if d != ax]
        rows = x.transpose(keep + [ax]).reshape(-1, x.shape[ax])
        xdt = self.dtype[rows[0, 0]] if rows.size else np.dtype(np.float64)
        better = "gt" if op == "argmax" else "lt"
        out = []
        for r in rows:
            best, at = r[0], self.const(0, dtype)
            for j in range(1, len(r)):
                take = self.node(better, (r[j], best), np.bool_)
                if xdt.kind == "f":  # a NaN beats a number; the first NaN stays
                    nan_j = self.node("ne", (r[j], r[j]), np.bool_)
                    num_best = self.node("eq", (best, best), np.bool_)
                    take = self.node("or", (take, self.node("and", (nan_j, num_best), np.bool_)), np.bool_)
                best = self.node("sel", (take, r[j], best), xdt)
                at = self.node("sel", (take, self.const(j, dtype), at), dtype)
            out.append(at)
        return np.array(out, dtype=object).reshape(shape)

    def _less(self, a, b, dts):
        """Whether key tuple ``a`` sorts before ``b`` (lexicographic; floats in the total order of ``lax.sort``:
        -NaN < -inf < ... < -0 < 0 < ... < inf < NaN)."""
        less = None
        for x, y, dt in zip(reversed(a), reversed(b), reversed(dts), strict=True):
            lt = self.node("lt_to" if dt.kind == "f" else "lt", (x, y), np.bool_)
            if less is None:
                less = lt
            else:
                eq = self.node("eq_to" if dt.kind == "f" else "eq", (x, y), np.bool_)
                less = self.node("or", (lt, self.node("and", (eq, less), np.bool_)), np.bool_)
        return less

    def sort(self, ins, dim, num_keys, dts):
        """``lax.sort`` of run-time values along ``dim`` (the first ``num_keys`` operands the keys, the others
        carried along: ``argsort``, a sort's derivative): an odd-even transposition network of n rounds, which
        exchanges only strictly out-of-order neighbours and so is stable, as ``lax.sort``."""
        n = ins[0].shape[dim]
        moved = [np.moveaxis(x, dim, -1).copy() for x in ins]
        for idx in np.ndindex(*moved[0].shape[:-1]):
            cols = [[m[idx + (j,)] for j in range(n)] for m in moved]
            for rnd in range(n):
                for j in range(rnd % 2, n - 1, 2):
                    swap = self._less([c[j + 1] for c in cols[:num_keys]], [c[j] for c in cols[:num_keys]],
                                      dts[:num_keys])
                    for c, dt in zip(cols, dts, strict=True):
                        lo, hi = c[j], c[j + 1]
                        c[j] = self.node("sel", (swap, hi, lo), dt)
                        c[j + 1] = self.node("sel", (swap, lo, hi), dt)
            for m, c in zip(moved, cols, strict=True):
                for j in range(n):
                    m[idx + (j,)] = c[j]
        return [np.moveaxis(m, -1, dim) for m in moved]

    def cumulative(self, op, x, axis, reverse, dtype):
        """``cumsum``, ``cumprod``, ``cummax``, ``cummin`` along ``axis`` (from the end if ``reverse``)."""
        out = np.moveaxis(x, axis, -1).copy()
        n = out.shape[-1]
        order = range(n - 1, -1, -1) if reverse else range(n)
        # XLA's cumsum of two terms or more starts each sum from +0 (never -0), as its reduce_sum
        init = op == "add" and np.dtype(dtype).kind == "f" and n >= 2
        for idx in np.ndindex(*out.shape[:-1]):
            acc = None
            for j in order:
                acc = out[idx + (j,)] if acc is None else self.node(op, (acc, out[idx + (j,)]), dtype)
                out[idx + (j,)] = self.node("add", (acc, self.const(0.0, dtype)), dtype) if init else acc
        return np.moveaxis(out, -1, axis)

    def cholesky(self, a, dtype):
        """The lower Cholesky factor of a run-time matrix (its lower triangle read), zeros above the diagonal, as
        XLA's ``potrf`` (SciPy's OpenBLAS) computes it column by column: a pivot ``d`` that is not > 0 makes the
        whole factor NaN, as XLA's (a NaN pivot is no failure there: it runs on as NaN); the column below it is
        its entries, less their dot products with the factor's rows, times the reciprocal of sqrt(d), which
        BLAS's scaling by 0 (an infinite pivot) makes 0, not NaN."""
        if a.ndim != 2 or a.shape[0] != a.shape[1] or np.dtype(dtype) != np.float64:
            raise UnsupportedPrimitive(f"cholesky of shape {a.shape} (only square float64, unbatched)")
        n = a.shape[0]
        L = np.empty((n, n), dtype=object)
        zero = self.const(0.0, dtype)
        one = self.const(1.0, dtype)
        ok = None

        def less_dot(x, row_i, row_j, j):
            if j == 0:
                return x
            return self.node("sub", (x, self.total([self.node("mul", (L[row_i, k], L[row_j, k]), dtype)
                                                    for k in range(j)], dtype)), dtype)

        for j in range(n):
            d = less_dot(a[j, j], j, j, j)
            fails = self.node("le", (d, zero), np.bool_)
            ok = self.node("not", (fails,), np.bool_) if ok is None else \
                self.node("and", (ok, self.node("not", (fails,), np.bool_)), np.bool_)
            L[j, j] = self.node("sqrt", (d,), dtype)
            r = self.node("div", (one, L[j, j]), dtype)
            by_zero = self.node("eq", (r, zero), np.bool_)
            for i in range(j + 1, n):
                t = less_dot(a[i, j], i, j, j)
                L[i, j] = self.node("sel", (by_zero, zero, self.node("mul", (t, r), dtype)), dtype)
            for i in range(j):
                L[i, j] = zero
        nan = self.const(np.nan, dtype)
        return np.array([[self.node("sel", (ok, L[i, j], nan), dtype) for j in range(n)] for i in range(n)],
                        dtype=object)

    def dot_general(self, a, b, dims, shape, dtype):
        (ca, cb), (ba, bb) = dims
        ca, cb, ba, bb = (tuple(int(d) for d in t) for t in (ca, cb, ba, bb))
        fa = [d for d in range(a.ndim) if d not in ca and d not in ba]
        fb = [d for d in range(b.ndim) if d not in cb and d not in bb]
        A = a.transpose(list(ba) + fa + list(ca))
        B = b.transpose(list(bb) + fb + list(cb))
        nb = int(np.prod([a.shape[d] for d in ba], dtype=np.int64))
        na = int(np.prod([a.shape[d] for d in fa], dtype=np.int64))
        nbf = int(np.prod([b.shape[d] for d in fb], dtype=np.int64))
        nc = int(np.prod([a.shape[d] for d in ca], dtype=np.int64))
        A = A.reshape(nb, na, nc)
        B = B.reshape(nb, nbf, nc)
        out = np.empty((nb, na, nbf), dtype=object)
        for i in range(nb):
            for j in range(na):
                for k in range(nbf):
                    out[i, j, k] = self.total([self.node("mul", (A[i, j, c], B[i, k, c]), dtype) for c in range(nc)],
                                              dtype, xla=True)
        return out.reshape(shape)

    # --- blocks of array code -------------------------------------------------------------------------------
    def block(self, eqn, ins, idt):
        """Array C for an equation with no scalar form here (an LU factorization, a triangular solve): the
        inputs packed into local arrays, the array translator's code, the outputs read back as nodes."""
        tr = Translator()
        tr.indent = 1
        tr._n = 10**6 * (self.counter[0] + 1)  # its names cannot clash with ours
        tr.within = list(self.within)  # the calls around the equation, and the equation (as in its own run)
        tr.begin(root=True)
        vals = [Val(tuple(x.shape), d, name=tr.fresh("b")) for x, d in zip(ins, idt, strict=True)]
        outs = tr.equation(eqn, vals)
        tr.end()
        bname = self.fresh("blk")
        out_nodes, copies, off = [], [], 0
        total = sum(o.size for o in outs)
        for o in outs:
            res = np.empty(o.shape, dtype=object)
            for k, idx in enumerate(np.ndindex(*o.shape)):
                res[idx] = self.leaf(f"{bname}_{ctype(o.dtype)[0]}[{off + k}]", o.dtype)
                copies.append((f"{bname}_{ctype(o.dtype)[0]}[{off + k}]", tr.elem(o, k)))
            off += o.size
            out_nodes.append(res)
        dtypes = sorted({ctype(o.dtype) for o in outs})
        in_flat = [x.ravel() for x in ins]
        self.scope.stmts.append(("block", bname, total, dtypes, vals, in_flat, tr.lines, copies,
                                 [n for r in out_nodes for n in r.ravel()]))
        # the block's outputs depend on its inputs: a leaf carries them for the liveness pass
        for r in out_nodes:
            for n in r.ravel():
                self.args[n] = tuple(int(i) for x in in_flat for i in x)
        return out_nodes

    # --- control flow ---------------------------------------------------------------------------------------
    def while_loop(self, params, ins):
        nc, nb = params["cond_nconsts"], params["body_nconsts"]
        cconsts, bconsts, init = ins[:nc], ins[nc:nc + nb], ins[nc + nb:]
        carry_names, carry_leaves = self._carry(init)
        outer = self.scope
        cond_scope = Scope(outer)
        self.scope = cond_scope
        # a loop's body is a computation of its own in XLA: a converted boolean enters it as a parameter
        cconsts, bconsts = [x.copy() for x in cconsts], [x.copy() for x in bconsts]
        (pred,) = self.run(params["cond_jaxpr"].jaxpr, params["cond_jaxpr"].consts, cconsts + carry_leaves)
        body_scope = Scope(outer)
        self.scope = body_scope
        new = self.run(params["body_jaxpr"].jaxpr, params["body_jaxpr"].consts, bconsts + carry_leaves)
        self.scope = outer
        assigns = [(nm, n) for names, vals in zip(carry_names, new, strict=True)
                   for nm, n in zip(names.ravel(), vals.ravel(), strict=True)]
        inits = [(nm, n) for names, vals in zip(carry_names, init, strict=True)
                 for nm, n in zip(names.ravel(), vals.ravel(), strict=True)]
        dts = {nm: self.dtype[lf] for lv in carry_leaves for nm, lf in
               zip([self.value[i] for i in lv.ravel()], lv.ravel(), strict=True)}
        self.scope.stmts.append(("while", inits, cond_scope, pred.ravel()[0], body_scope, assigns, dts))
        # after the loop, the carries hold the results
        outs = []
        for names, x in zip(carry_names, init, strict=True):
            res = np.empty(x.shape, dtype=object)
            for idx in np.ndindex(*x.shape):
                res[idx] = self.leaf(names[idx], self.dtype[x[idx]])
            outs.append(res)
        return outs

    def _carry(self, init):
        """C variables for loop carries: their names and the leaves that read them."""
        names, leaves = [], []
        for x in init:
            nm = np.empty(x.shape, dtype=object)
            lf = np.empty(x.shape, dtype=object)
            for idx in np.ndindex(*x.shape):
                nm[idx] = self.fresh("c")
                lf[idx] = self.leaf(nm[idx], self.dtype[x[idx]])
            names.append(nm)
            leaves.append(lf)
        return names, leaves

    def scan(self, params, ins):
        """A ``scan`` with neither inputs nor outputs per iteration (``fori_loop``'s form): a counted C loop."""
        nc, ncar, length = params["num_consts"], params["num_carry"], int(params["length"])
        jaxpr = params["jaxpr"]
        if len(ins) != nc + ncar or len(jaxpr.jaxpr.outvars) != ncar:
            return self.unrolled_scan(params, ins)
        consts, init = ins[:nc], ins[nc:]
        names, leaves = self._carry(init)
        outer = self.scope
        body = Scope(outer)
        self.scope = body
        new = self.run(jaxpr.jaxpr, jaxpr.consts, [x.copy() for x in consts] + leaves)  # parameters, as in XLA
        self.scope = outer
        flat = lambda arrs: [(nm, n) for a, b in arrs for nm, n in zip(a.ravel(), b.ravel(), strict=True)]  # noqa: E731
        dts = {self.value[i]: self.dtype[i] for lv in leaves for i in lv.ravel()}
        self.scope.stmts.append(("for", flat(zip(names, init, strict=True)), length, body,
                                 flat(zip(names, new, strict=True)), dts))
        return [np.array([self.leaf(nm, dts[nm]) for nm in a.ravel()], dtype=object).reshape(a.shape) for a in names]

    def unrolled_scan(self, params, ins):
        """A ``scan`` with inputs or outputs per iteration (``lax.scan`` over a fixed sequence, a ``fori_loop``
        under reverse-mode differentiation, ``expm``'s squarings), unrolled: its length is fixed, and each
        copy of the body folds its own constants. Refused above :data:`UNROLL_MAX` equations in all."""
        nc, ncar, length = params["num_consts"], params["num_carry"], int(params["length"])
        jaxpr = params["jaxpr"]
        if length * max(jaxpr_size(jaxpr.jaxpr), 1) > UNROLL_MAX:
            raise UnsupportedPrimitive(f"scan with per-iteration inputs or outputs over {length} iterations of "
                                       f"{jaxpr_size(jaxpr.jaxpr)} equations (unrolled up to {UNROLL_MAX} in all)")
        # XLA's loop body: its inputs are parameters there (copies: no converted boolean seen through them)
        consts, carry, xs = [x.copy() for x in ins[:nc]], [x.copy() for x in ins[nc:nc + ncar]], ins[nc + ncar:]
        ys = [None] * length
        for i in (range(length - 1, -1, -1) if params.get("reverse", False) else range(length)):
            outs = self.run(jaxpr.jaxpr, jaxpr.consts, consts + carry + [x[i:i + 1].reshape(x.shape[1:]) for x in xs])
            carry, ys[i] = [x.copy() for x in outs[:ncar]], outs[ncar:]
        n_ys = len(jaxpr.jaxpr.outvars) - ncar
        stacked = [np.stack([ys[i][k] for i in range(length)]) if length else
                   np.empty((0,) + tuple(jaxpr.jaxpr.outvars[ncar + k].aval.shape), dtype=object)
                   for k in range(n_ys)]
        return carry + stacked

    def cond(self, params, ins):
        index, ops = ins[0], ins[1:]
        branches = params["branches"]
        i0 = index.ravel()[0]
        if not self.is_const(i0):  # an XLA conditional's branches take their operands as parameters
            ops = [self._behind_barrier(x) for x in ops]
        if self.is_const(i0):
            k = int(np.clip(int(self.cval(i0)), 0, len(branches) - 1))
            return self.run(branches[k].jaxpr, branches[k].consts, ops)
        names = [np.array([self.fresh("c") for _ in range(int(np.prod(v.aval.shape, dtype=np.int64)))],
                          dtype=object).reshape(v.aval.shape) for v in branches[0].jaxpr.outvars]
        dts = {nm: np.dtype(v.aval.dtype) for arr, v in zip(names, branches[0].jaxpr.outvars, strict=True)
               for nm in arr.ravel()}
        outer = self.scope
        arms = []
        for br in branches:
            sc = Scope(outer)
            self.scope = sc
            res = self.run(br.jaxpr, br.consts, ops)
            arms.append((sc, [(nm, n) for arr, r in zip(names, res, strict=True)
                              for nm, n in zip(arr.ravel(), r.ravel(), strict=True)]))
        self.scope = outer
        outs = [np.array([self.leaf(nm, dts[nm]) for nm in arr.ravel()], dtype=object).reshape(arr.shape)
                for arr in names]
        leaves = {nm: int(lf) for arr, o in zip(names, outs, strict=True)
                  for nm, lf in zip(arr.ravel(), o.ravel(), strict=True)}
        self.scope.stmts.append(("cond", i0, arms, dts, leaves))
        return outs

    # --- writing C ------------------------------------------------------------------------------------------
    def _live(self, roots: list[int]) -> set[int]:
        live: set[int] = set()
        stack = list(roots)
        while stack:
            i = stack.pop()
            if i in live:
                continue
            live.add(i)
            stack.extend(self.args[i] if isinstance(self.args[i], tuple) else ())
        return live

    def _live_all(self, outputs: list[int], root_scope: Scope) -> set[int]:
        """The nodes the outputs need, with what loops and switches read: a fixpoint, as a ``cond``'s result
        that nothing reads is neither declared nor computed in its branches."""
        live: set[int] = set()
        while True:
            new = self._live(outputs + self._stmt_roots(root_scope, live))
            if new == live:
                return live
            live = new

    def _stmt_roots(self, scope: Scope, live: set[int]) -> list[int]:
        roots = []
        for st in scope.stmts:
            if st[0] == "while":
                _, inits, cs, pred, bs, assigns, _ = st
                roots += [n for _, n in inits] + [pred] + [n for _, n in assigns]
                roots += self._stmt_roots(cs, live) + self._stmt_roots(bs, live)
            elif st[0] == "for":
                _, inits, _, bs, assigns, _ = st
                roots += [n for _, n in inits] + [n for _, n in assigns] + self._stmt_roots(bs, live)
            elif st[0] == "cond":
                roots.append(st[1])
                for sc, asg in st[2]:
                    roots += [n for nm, n in asg if st[4][nm] in live] + self._stmt_roots(sc, live)
        return roots

    def emit_body(self, outputs: list[tuple[str, int]]) -> str:
        """The C statements of the whole graph for ``outputs`` (C lvalue, node) pairs."""
        root_scope = self.scope
        while root_scope.parent is not None:
            root_scope = root_scope.parent
        live = self._live_all([n for _, n in outputs], root_scope)
        lines: list[str] = []
        self._write(root_scope, live, lines, 1)
        for lv, n in outputs:
            lines.append(f"    {lv} = {self.expr(n)};")
        return "\n".join(lines) + "\n"

    def emit_lanes(self, outputs: list[tuple[str, int]]) -> str:
        """As :meth:`emit_body`, for ``LANES`` trials at once (SIMD across trials): every value that differs
        between trials is a GCC/Clang vector (``lane_f64``, ``lane_i32``; a boolean is a ``lane_i64`` mask of -1
        and 0), and values from parameters and times alone stay scalars. Arithmetic, comparisons, selects, min
        and max, conversions and ``isfinite``/``abs`` are vector expressions; other functions (sin, sqrt, ...)
        are loops over the lanes. A ``while`` runs until no lane's test holds, and a lane whose test fails keeps
        its carry (``vmap``'s semantics), so each lane computes the scalar code's values. A ``cond`` runs each arm
        that some lane takes (one, where the lanes agree: trials on one sample grid) and each lane reads the
        results of its own arm (:meth:`_write_lane_cond`). Outputs are ``(lvalue, node)``, written
        ``lvalue[l]`` per lane. Array blocks have no lane form (UnsupportedPrimitive)."""
        root_scope = self.scope
        while root_scope.parent is not None:
            root_scope = root_scope.parent
        live = self._live_all([n for _, n in outputs], root_scope)
        lines: list[str] = []
        self.lanes, self.active = True, None
        try:
            self._write(root_scope, live, lines, 1)
            for lv, n in outputs:
                lines.append(f"    for (int l = 0; l < LANES; l++) {lv}[l] = {self.expr(n)};")
        finally:
            self.lanes, self.active = False, None
        return "\n".join(lines) + "\n"

    def _vec(self, i: int) -> str:
        """Node ``i`` as a whole lane vector (a scalar broadcast)."""
        if self.is_const(i) or i in self.shared:
            e = self.expr(i)
            dt = self.dtype[i]
            return f"LANE_MASK({e})" if dt == np.bool_ else f"(({lane_type(dt)}){{0}} + ({e}))"
        return self.value[i] if self.op[i] == "leaf" else f"n{i}"

    def _vrhs(self, i: int) -> str | None:
        """The vector expression of node ``i``, or None (then a loop over lanes)."""
        op, a, dt = self.op[i], self.args[i], self.dtype[i]
        e = [self._vec(x) for x in a]
        kind = self.dtype[a[0]].kind if a else "f"
        arith = {"add": "+", "sub": "-", "mul": "*", "div": "/"}
        if op in arith and dt.kind in "fi" and not (dt.kind == "i" and op == "div"):
            return f"({e[0]}) {arith[op]} ({e[1]})"
        if op == "neg" and dt.kind in "fi":
            return f"-({e[0]})"
        if op == "ipow" and dt.kind == "f":
            p = self.value[i]
            prod = " * ".join([f"({e[0]})"] * abs(p)) if p else f"(({e[0]}) * 0.0 + 1.0)"
            return f"1.0 / ({prod})" if p < 0 else prod
        cmp = {"lt": "<", "le": "<=", "gt": ">", "ge": ">=", "eq": "==", "ne": "!="}
        if op in cmp:
            if kind == "b" and op not in ("eq", "ne"):
                return None  # an order of masks (-1 true) is not that of booleans: a loop over lanes
            c = f"({e[0]}) {cmp[op]} ({e[1]})"
            return c if kind in "fb" else f"__builtin_convertvector({c}, lane_i64)"
        if dt == np.bool_ and op in ("and", "or", "xor", "not", "max", "min"):
            sym = {"and": "&", "or": "|", "xor": "^", "max": "|", "min": "&"}
            return f"~({e[0]})" if op == "not" else f"({e[0]}) {sym[op]} ({e[1]})"
        if op == "sel":
            return f"LANE_SEL_{LANE_SUFFIX[dt.str]}({e[0]}, {e[1]}, {e[2]})"
        if op in ("max", "min") and dt.kind == "f":
            return f"lane_{op}({e[0]}, {e[1]})"
        if op in ("max", "min") and dt == np.int32:
            test = f"__builtin_convertvector(({e[0]}) {'>' if op == 'max' else '<'} ({e[1]}), lane_i64)"
            return f"LANE_SEL_I32({test}, {e[0]}, {e[1]})"
        if op == "is_finite":
            return f"(({e[0]}) - ({e[0]})) == (({e[0]}) - ({e[0]}))"
        if op == "abs" and dt.kind == "f":
            return f"(lane_f64)((lane_i64)({e[0]}) & 0x7fffffffffffffffLL)"
        if op == "convert":
            src = self.dtype[a[0]]
            if src == dt:
                return e[0]
            if dt == np.bool_:
                zero = "0.0" if src.kind == "f" else "0"
                c = f"({e[0]}) != (({lane_type(src)}){{0}} + {zero})"
                return c if src.itemsize == 8 else f"__builtin_convertvector({c}, lane_i64)"
            if src.kind == "f" and dt.kind in "iu":
                return None  # saturated, NaN to 0, as XLA: a loop over lanes
            x = f"-({e[0]})" if src == np.bool_ else e[0]
            return f"__builtin_convertvector({x}, {lane_type(dt)})"
        if op in ("stop_gradient", "copy", "copy_p", "reduce_precision", "optimization_barrier", "real"):
            return e[0]
        return None

    def _lane_node(self, i: int, pad: str) -> str:
        """The statement of node ``i`` in lane code: a scalar if it is the same in every lane, else a vector
        expression, else a loop over the lanes."""
        loop = "for (int l = 0; l < LANES; l++)"
        dt, args = self.dtype[i], self.args[i]
        if all(a in self.shared or self.is_const(a) for a in args):
            # the same in every lane (from parameters and times only): one scalar
            self.shared.add(i)
            return f"{pad}const {ctype(dt)} n{i} = {self.rhs(i)};"
        v = self._vrhs(i)
        if v is not None:
            return f"{pad}const {lane_type(dt)} n{i} = {v};"
        # in a cond's arm, a lane that does not take it calls no function (an integer division by zero there
        # would trap): its value is 0, which no lane reads
        act = f"{self.active}[l] && " if self.active is not None else ""
        split = self._split_select(i)
        if split is not None:
            expr, read = split  # the nodes it reads through may be read by nothing else: (void), for -Wall
            if act:
                expr = f"({act}1) ? ({expr}) : 0"
            return f"{pad}{lane_type(dt)} n{i}; {loop} n{i}[l] = {expr};" + "".join(f" (void)n{k};" for k in read)
        if dt == np.bool_:
            return f"{pad}lane_i64 n{i}; {loop} n{i}[l] = ({act}({self.rhs(i)})) ? -1 : 0;"
        if act:
            return f"{pad}{lane_type(dt)} n{i}; {loop} n{i}[l] = ({act}1) ? ({self.rhs(i)}) : 0;"
        return f"{pad}{lane_type(dt)} n{i}; {loop} n{i}[l] = {self.rhs(i)};"

    _SPLIT_THROUGH = ("add", "sub", "mul", "div", "neg")

    def _split_select(self, i: int) -> tuple[str, list[int]] | None:
        """For a function with no vector form (``sin``, ``exp``, ...) of a select with a constant arm, possibly
        through arithmetic with constants and shared values (``sin(where(small, 1.0, x) / 2)``, as Lie groups'
        guarded series write it): the lane's expression as a select of the function of each arm,
        ``c ? sin(1.0 / 2) : sin(x / 2)``, and the nodes it reads through; or None. Lane by lane the same value
        (the function of the arm the select takes, computed the same way); the constant arm is folded, so the
        lane calls the function only where it takes the other arm (a guarded series' common case calls none),
        and the call on the other arm is the one the code makes elsewhere (``sin(x)`` beside
        ``sin(where(small, 1.0, x))``)."""
        args = self.args[i]
        if len(args) != 1 or self.dtype[i].kind != "f" or self.dtype[args[0]].kind != "f":
            return None
        chain, j = [], args[0]
        while self.op[j] != "sel" and self.op[j] in self._SPLIT_THROUGH and len(chain) < 4:
            lane_args = [x for x in self.args[j] if not (self.is_const(x) or x in self.shared)]
            if len(lane_args) != 1:
                return None
            chain.append(j)
            j = lane_args[0]
        if self.op[j] != "sel" or j in self.shared:
            return None
        c, on_true, on_false = self.args[j]
        if not (self.is_const(on_true) or self.is_const(on_false)):
            return None

        def through(arm: int) -> str:
            sub = {j: f"({self.expr(arm)})"}
            for k in reversed(chain):  # innermost first
                sub[k] = f"({self.rhs(k, sub)})"
            return self.rhs(i, sub)

        return f"({self.expr(c)}) ? ({through(on_true)}) : ({through(on_false)})", [j, *chain]

    def _write(self, scope: Scope, live: set[int], lines: list[str], depth: int) -> None:
        """The C of a scope's statements: scalar code, or lane code while ``self.lanes`` (:meth:`emit_lanes`),
        where values are typed and read as lane vectors, a loop runs while any lane's test holds and a lane
        whose test fails keeps its carry."""
        pad = "    " * depth
        lanes = self.lanes
        typ = lane_type if lanes else ctype
        val = self._vec if lanes else self.expr
        for st in scope.stmts:
            kind = st[0]
            if kind == "node":
                i = st[1]
                if i in live:
                    lines.append(self._lane_node(i, pad) if lanes else
                                 f"{pad}const {ctype(self.dtype[i])} n{i} = {self.rhs(i)};")
            elif lanes and kind == "cond":
                self._write_lane_cond(st, live, lines, depth)
            elif lanes and kind == "block":
                raise UnsupportedPrimitive(f"{kind!r} has no lane form (the batch runs one trial at a time)")
            elif kind == "block":
                _, bname, total, dtypes, vals, in_flat, blines, copies, outs = st
                if not any(o in live for o in outs):
                    continue
                for ct in dtypes:
                    lines.append(f"{pad}{ct} {bname}_{ct[0]}[{total}];")
                lines.append(f"{pad}{{")
                for v, flat in zip(vals, in_flat, strict=True):
                    items = ", ".join(self.expr(int(n)) for n in flat) or "0"
                    lines.append(f"{pad}    {ctype(v.dtype)} {v.name}[{max(v.size, 1)}] = {{{items}}};")
                lines.extend(pad + ln for ln in blines)
                lines.extend(f"{pad}    {lhs} = {rhs};" for lhs, rhs in copies)
                lines.append(f"{pad}}}")
            elif kind == "while":
                _, inits, cs, pred, bs, assigns, dts = st
                for nm, n in inits:
                    lines.append(f"{pad}{typ(dts[nm])} {nm} = {val(n)};")
                lines.append(f"{pad}for (;;) {{")
                self._write(cs, live, lines, depth + 1)
                if lanes:
                    # in a cond's arm, the lanes that do not take it stop at once (their test may never fail)
                    act = "" if self.active is None else f" & {self.active}"
                    lines.append(f"{pad}    const lane_i64 go = ({self._vec(pred)}){act};")
                    lines.append(f"{pad}    int any = 0;")
                    lines.append(f"{pad}    for (int l = 0; l < LANES; l++) any |= go[l] != 0;")
                    lines.append(f"{pad}    if (!any) break;")
                else:
                    lines.append(f"{pad}    if (!({self.expr(pred)})) break;")
                lines.append(f"{pad}    {{")
                self._write(bs, live, lines, depth + 2)
                for nm, n in assigns:
                    lines.append(f"{pad}        const {typ(dts[nm])} {nm}_next = {val(n)};")
                for nm, _ in assigns:
                    new = f"LANE_SEL_{LANE_SUFFIX[dts[nm].str]}(go, {nm}_next, {nm})" if lanes else f"{nm}_next"
                    lines.append(f"{pad}        {nm} = {new};")
                lines.append(f"{pad}    }}")
                lines.append(f"{pad}}}")
            elif kind == "for":
                _, inits, length, bs, assigns, dts = st
                for nm, n in inits:
                    lines.append(f"{pad}{typ(dts[nm])} {nm} = {val(n)};")
                it = self.fresh("it")
                lines.append(f"{pad}for (int {it} = 0; {it} < {length}; {it}++) {{")
                self._write(bs, live, lines, depth + 1)
                for nm, n in assigns:
                    lines.append(f"{pad}    const {typ(dts[nm])} {nm}_next = {val(n)};")
                for nm, _ in assigns:
                    lines.append(f"{pad}    {nm} = {nm}_next;")
                lines.append(f"{pad}}}")
            elif kind == "cond":
                _, i0, arms, dts, leaves = st
                if not any(leaves[nm] in live for nm in dts):
                    continue
                for nm, dt in dts.items():
                    if leaves[nm] in live:
                        lines.append(f"{pad}{ctype(dt)} {nm};")
                lines.append(f"{pad}switch ((int)({self.expr(i0)})) {{")
                for k, (sc, asg) in enumerate(arms):
                    lines.append(f"{pad}{'default' if k == len(arms) - 1 else f'case {k}'}: {{")
                    self._write(sc, live, lines, depth + 1)
                    for nm, n in asg:
                        if leaves[nm] in live:
                            lines.append(f"{pad}    {nm} = {self.expr(n)};")
                    lines.append(f"{pad}    break;")
                    lines.append(f"{pad}}}")
                lines.append(f"{pad}}}")


    def _write_lane_cond(self, st, live: set[int], lines: list[str], depth: int) -> None:
        """The lane code of a ``cond``: each lane takes the arm its index names (as the scalar ``switch``:
        ``case k``, the last arm the default), every arm that some lane takes runs in lane form, once for all
        lanes, under the mask of the lanes that take it, and each result is selected lane by lane from the arm
        its lane took. Where the lanes agree (the usual case: trials on one sample grid) one arm runs. In an
        arm, a lane that does not take it calls no function and leaves its loops at once (:meth:`_lane_node`),
        and what it computes there (an infinity, a NaN) is never selected: each lane has the scalar code's
        bits."""
        _, i0, arms, dts, leaves = st
        if not any(leaves[nm] in live for nm in dts):
            return
        pad = "    " * depth
        for nm, dt in dts.items():
            if leaves[nm] in live:
                lines.append(f"{pad}{lane_type(dt)} {nm} = {{0}};")
        ix = self.fresh("ix")
        if self.is_const(i0) or i0 in self.shared:
            lines.append(f"{pad}const int {ix} = (int)({self.expr(i0)});")
            lane_ix = ix
        else:
            lines.append(f"{pad}const {lane_type(self.dtype[i0])} {ix} = {self._vec(i0)};")
            lane_ix = f"(int)({ix}[l] != 0)" if self.dtype[i0] == np.bool_ else f"(int){ix}[l]"
        outer, last = self.active, len(arms) - 1
        try:
            for k, (sc, asg) in enumerate(arms):
                act = self.fresh("act")
                takes = f"{lane_ix} == {k}" if k < last else (f"({lane_ix} < 0 || {lane_ix} >= {last})" if last
                                                                else "1")
                within = f"{outer}[l] && " if outer is not None else ""
                lines.append(f"{pad}{{")
                lines.append(f"{pad}    lane_i64 {act}; int any_{act} = 0;")
                lines.append(f"{pad}    for (int l = 0; l < LANES; l++) {{ {act}[l] = ({within}{takes}) ? -1 : 0; "
                             f"any_{act} |= {act}[l] != 0; }}")
                lines.append(f"{pad}    if (any_{act}) {{")
                self.active = act
                self._write(sc, live, lines, depth + 2)
                for nm, n in asg:
                    if leaves[nm] in live:
                        sel = f"LANE_SEL_{LANE_SUFFIX[dts[nm].str]}"
                        lines.append(f"{pad}        {nm} = {sel}({act}, {self._vec(n)}, {nm});")
                self.active = outer
                lines.append(f"{pad}    }}")
                lines.append(f"{pad}}}")
        finally:
            self.active = outer


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


LANE_TYPES = {np.dtype(np.float64): "lane_f64", np.dtype(np.int32): "lane_i32", np.dtype(np.int64): "lane_i64",
              np.dtype(np.uint32): "lane_u32",
              np.dtype(np.bool_): "lane_i64"}
"""The lane vector type of each dtype; a boolean is a mask of -1 (true) and 0, as vector comparisons give."""
LANE_SUFFIX = {np.dtype(np.float64).str: "F64", np.dtype(np.int32).str: "I32", np.dtype(np.int64).str: "I64",
               np.dtype(np.bool_).str: "I64", np.dtype(np.uint32).str: "U32"}


def lane_typedefs(lanes: int) -> str:
    """The lane vector types (GCC/Clang vector extensions) for ``lanes`` trials, and their selects, broadcast
    of a scalar boolean and NaN-propagating min and max (XLA's, as ``lm_max``: of equal values, the bits of
    both and-ed for the max, or-ed for the min, so that +0 and -0 give +0 and -0)."""
    return f"""#define LANES {lanes}
typedef double lane_f64 __attribute__((vector_size({8 * lanes})));
typedef int32_t lane_i32 __attribute__((vector_size({4 * lanes})));
typedef uint32_t lane_u32 __attribute__((vector_size({4 * lanes})));
typedef int64_t lane_i64 __attribute__((vector_size({8 * lanes})));
#define LANE_MASK(b) (((lane_i64){{0}}) - (int64_t)((b) != 0))
#define LANE_SEL_I64(c, a, b) (((c) & (a)) | (~(c) & (b)))
static inline lane_f64 LANE_SEL_F64(lane_i64 c, lane_f64 a, lane_f64 b)
{{ return (lane_f64)((c & (lane_i64)a) | (~c & (lane_i64)b)); }}
static inline lane_i32 LANE_SEL_I32(lane_i64 c, lane_i32 a, lane_i32 b)
{{ const lane_i32 m = __builtin_convertvector(c, lane_i32); return (m & a) | (~m & b); }}
static inline lane_u32 LANE_SEL_U32(lane_i64 c, lane_u32 a, lane_u32 b)
{{ const lane_u32 m = __builtin_convertvector(c, lane_u32); return (m & a) | (~m & b); }}
static inline lane_f64 lane_max(lane_f64 a, lane_f64 b)
{{ return LANE_SEL_F64((a != a) | (b != b), a + b,
                       LANE_SEL_F64(a > b, a, LANE_SEL_F64(b > a, b, (lane_f64)((lane_i64)a & (lane_i64)b)))); }}
static inline lane_f64 lane_min(lane_f64 a, lane_f64 b)
{{ return LANE_SEL_F64((a != a) | (b != b), a + b,
                       LANE_SEL_F64(a < b, a, LANE_SEL_F64(b < a, b, (lane_f64)((lane_i64)a | (lane_i64)b)))); }}"""


def lane_type(dtype) -> str:
    """The lane vector type of a dtype."""
    dt = np.dtype(dtype)
    if dt not in LANE_TYPES:
        raise UnsupportedPrimitive(f"dtype {dt} has no lane type")
    return LANE_TYPES[dt]
