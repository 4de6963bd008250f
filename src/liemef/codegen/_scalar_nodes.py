"""The scalar translator's graph of nodes: its constants, scopes and the node graph itself (the base of
:class:`~._scalar_c.ScalarTranslator`), and the lane types of the batch kernels."""

from __future__ import annotations

import math
import struct

import numpy as np
from jax.extend import core as jcore

from ._primitives import (
    BINARY,
    BOOL_BINARY,
    BOOL_UNARY,
    FLOAT_BINARY,
    FLOAT_UNARY,
    INT_BINARY,
    INT_UNARY,
    ROUND_EVEN,
    UnsupportedPrimitive,
    ctype,
    float_to_int,
    int_division,
    integer_pow,
    literal,
    np_eval,
    saturated,
    shift_left,
    translating,
)

SCALAR_FOLD = {"neg", "add", "add_any", "sub", "mul", "div", "max", "min", "sin", "cos", "sqrt", "abs",
                "exp", "log", "eq", "ne", "lt", "le", "gt", "ge", "and", "or", "not", "is_finite",
                "stop_gradient"}
FOLDABLE = frozenset(SCALAR_FOLD | {"sel", "convert", "ipow"})
F64 = np.dtype(np.float64)
# float64 folds that Python's own arithmetic does exactly as NumPy's (IEEE double, round to nearest): no
# ufunc call and error-state context per folded constant (a first build folds thousands)
SIMPLIFIED = frozenset({"mul", "add", "add_any", "sub", "div", "neg", "sel", "and", "or", "stop_gradient", "copy",
                         "copy_p", "reduce_precision", "optimization_barrier", "real", "ipow", "convert"})
"""The operations :meth:`ScalarTranslator._simplify` may rewrite (the others it leaves at once)."""


def negative_zero(v) -> bool:
    """Whether the known value ``v`` is -0.0."""
    return v == 0 and math.copysign(1.0, float(v)) < 0


PY_F64 = {"add": float.__add__, "add_any": float.__add__, "sub": float.__sub__, "mul": float.__mul__}


LOOKUP_MIN = 8
"""A run-time index into a constant operand over more places than this reads a C array (fewer: selects)."""
UNROLL_MAX = 20000
"""The most equations an unrolled ``scan`` (:meth:`ScalarTranslator.unrolled_scan`) may copy."""
F64_BYTES = struct.Struct("=d").pack  # as np.float64(v).tobytes(): native order
CUMULATIVE = {"cumsum": "add", "cumprod": "mul", "cummax": "max", "cummin": "min"}


class Scope:
    """A C block: the nodes created in it, in order, and its table of common subexpressions."""

    def __init__(self, parent: Scope | None):
        self.parent = parent
        self.nodes: list[int] = []
        self.cse: dict = {}
        self.stmts: list = []  # ("node", id) | ("while", ...) | ("block", ...) in order


class ScalarNodes:
    """The scalar graph: nodes, constants, folding and the exact simplifications, hash-consed in scopes; the
    run of a jaxpr's equations (:class:`~._scalar_c.ScalarTranslator`'s first part)."""

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
        if type(value) is float and dt is F64:  # the common case, without a NumPy round trip
            v = value
            key = ("const", F64.str, F64_BYTES(v), pinned)
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
        if op in FOLDABLE:
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
        if dt is F64 and op in PY_F64 and all(self.dtype[a] is F64 for a in args):
            v = self.value
            return PY_F64[op](float(v[args[0]]), float(v[args[1]]))
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
        if op not in SIMPLIFIED:
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
                if c[k] and v[k] == 0 and (not real or negative_zero(v[k]) or self._never_negative_zero(a[1 - k])):
                    return a[1 - k]
            if op == "add_any" or a[0] > a[1]:
                return self.node("add", tuple(sorted(a)), dt)
        elif op == "sub":
            if c[1] and v[1] == 0 and not (real and negative_zero(v[1])):
                return a[0]
            if c[0] and v[0] == 0 and real and negative_zero(v[0]):
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
            with translating(self.within, eqn):
                outs = self.equation(eqn, ins)
            for var, o in zip(eqn.outvars, outs, strict=True):
                env[var] = np.asarray(o, dtype=object).reshape(var.aval.shape)
            self._note_pred(eqn, ins, env)
        return [read(a) for a in jaxpr.outvars]


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
