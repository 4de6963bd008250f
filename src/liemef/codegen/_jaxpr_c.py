r"""C99 for a jaxpr: the translator behind :func:`liemef.codegen.export_c`.

A traced JAX function (a ``ClosedJaxpr``) becomes one C function over fixed-size arrays, with no heap, no
library but ``<math.h>``, and every derivative the trace holds (``jacfwd``, ``hessian``) as plain arithmetic.

How it works, in one pass over the equations:

* **Values.** Each jaxpr variable is a C array (``double v12[6]``, ``int32_t``, ``_Bool``) in row-major order,
  or a known constant (a literal, a traced constant, or the result of an equation whose inputs are all known:
  those are evaluated in Python, *constant folding*, so iotas, index arithmetic and zero tangents cost nothing).
* **Inlining.** Calls (``jit``, ``custom_jvp_call``, ``custom_vjp_call``, ``closed_call``, ``checkpoint``) are
  emitted in place; ``custom_linear_solve`` emits its ``solve`` jaxpr.
* **Structure by index maps.** Every primitive that only moves elements (``broadcast_in_dim``, ``reshape``,
  ``transpose``, ``slice``, ``pad``, ``concatenate``, ``stack``, ``split``, ``gather``/``scatter`` with known
  indices, ...) is run once in Python on arrays of element ids; the ids it returns say which input element
  each output element is. Reshapes that keep the order are aliases (no code).
* **Arithmetic.** Elementwise primitives are loops (or statements, for scalars); ``dot_general`` is nested
  loops over its batch, free and contracted axes; reductions are loops over an index table; ``lu`` and
  ``triangular_solve`` are unrolled-size loops (partial pivoting as LAPACK's ``getrf``).
* **Control flow.** ``while`` is a C ``for (;;)`` loop over carry arrays; ``cond`` a ``switch``.

The primitives covered are :data:`PRIMITIVES`; any other raises :class:`UnsupportedPrimitive` naming it, and
where in the traced Python it came from. The semantics follow XLA's on the CPU: NaN propagates through
``max``/``min``, integer division truncates, ``select_n`` picks by its predicate. Results agree with XLA's to
rounding (libm's ``sin``/``cos`` against XLA's own, summation order in reductions): the tests ask 1e-12.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.extend import core as jcore

from .._frames import eqn_frames
from ._primitives import (
    BINARY,
    BOOL_BINARY,
    BOOL_UNARY,
    CALLS,
    CONTROL,
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
    jaxpr_size,
    literal,
    np_eval,
    own_precision,
    refuse_choice,
    shift_left,
    subjaxprs,
    take_layout,
)


class Translator:
    """Emits C statements for jaxpr equations; one instance per generated source (names are unique in it)."""

    def __init__(self, table_limit: int = 16):
        self.lines: list[str] = []
        self.tables: dict[bytes, str] = {}
        self.table_lines: list[str] = []
        self.indent = 1
        self._n = 0
        self.table_limit = table_limit
        # dead-code elimination: the lines come in nodes (one per equation, loop scaffold, copy), each with
        # the arrays it defines and reads; only nodes that a root (an output, a loop test) needs are kept
        self.nodes: list[list] = []  # [first line, end line, defs, reads, root]
        self._open: list | None = None
        # a called jaxpr used more than once becomes a C function (once), not a copy per call
        self.calls: dict[int, int] = {}
        self.functions: dict[int, tuple[str, object]] = {}
        self.function_texts: list[str] = []
        self.function_min = 40
        self.within: list = []  # the equations being emitted, outermost first (a call's, then its body's)

    # --- names and tables ---------------------------------------------------------------------------------
    def fresh(self, prefix: str = "v") -> str:
        self._n += 1
        return f"{prefix}{self._n}"

    def emit(self, line: str) -> None:
        if self._open is None:  # scaffolding outside any node: a root of its own
            self.begin(root=True)
            self.lines.append("    " * self.indent + line)
            self.end()
            return
        self.lines.append("    " * self.indent + line)

    def begin(self, root: bool = False) -> None:
        """Open a node: the lines emitted until :meth:`end` stand or fall together."""
        assert self._open is None
        self._open = [len(self.lines), None, set(), set(), root]

    def end(self) -> None:
        node, self._open = self._open, None
        node[1] = len(self.lines)
        self.nodes.append(node)

    def _read(self, name: str | None) -> None:
        if name is not None and self._open is not None:
            self._open[3].add(name)

    def live_lines(self, start: int) -> list[str]:
        """The lines from ``start`` that the roots need (a fixpoint over the nodes' reads and defs)."""
        nodes = [nd for nd in self.nodes if nd[0] >= start]
        live = [nd[4] for nd in nodes]
        needed: set = set()
        for nd, lv in zip(nodes, live, strict=True):
            if lv:
                needed |= nd[3]
        changed = True
        while changed:
            changed = False
            for k, nd in enumerate(nodes):
                if not live[k] and nd[2] & needed:
                    live[k] = True
                    needed |= nd[3]
                    changed = True
        keep = np.zeros(len(self.lines) - start, bool)
        for nd, lv in zip(nodes, live, strict=True):
            if lv:
                keep[nd[0] - start:nd[1] - start] = True
        return [ln for ln, k in zip(self.lines[start:], keep, strict=True) if k]

    def table(self, values: np.ndarray) -> str:
        """A ``static const`` array holding ``values`` (deduplicated), for constants and index maps."""
        values = np.ascontiguousarray(values)
        if values.dtype.kind in "iu":
            values = values.astype(np.int32 if np.abs(values).max(initial=0) < 2**31 else np.int64)
        key = values.dtype.str.encode() + values.tobytes()
        if key not in self.tables:
            name = f"k{len(self.tables) + 1}"
            body = ", ".join(literal(x, values.dtype) for x in values.ravel())
            self.table_lines.append(f"static const {ctype(values.dtype)} {name}[{max(values.size, 1)}] = {{{body}}};")
            self.tables[key] = name
        return self.tables[key]

    def declare(self, shape, dtype) -> Val:
        v = Val(tuple(shape), np.dtype(dtype), name=self.fresh())
        if self._open is not None:
            self._open[2].add(v.name)
        self.emit(f"{ctype(v.dtype)} {v.name}[{max(v.size, 1)}];")
        return v

    # --- element access -------------------------------------------------------------------------------------
    def elem(self, v: Val, i) -> str:
        """C expression of element ``i`` (an int, or the name of a loop index) of ``v``."""
        self._read(v.name if v.const is None else None)
        if v.const is not None:
            flat = np.asarray(v.const).ravel()
            if flat.size == 1 or (flat == flat[0]).all() or (flat.dtype.kind == "f" and np.isnan(flat).all()):
                return literal(flat[0], v.dtype)
            if isinstance(i, int | np.integer):
                return literal(flat[int(i)], v.dtype)
            return f"{self.table(flat.astype(v.dtype))}[{i}]"
        if v.size == 1:
            return f"{v.name}[0]"
        return f"{v.name}[{i}]"

    def loop(self, n: int, body) -> None:
        """``body(i)`` for i < n: a statement for n = 1, a C loop otherwise."""
        if n == 1:
            self.emit(body(0))
        else:
            i = self.fresh("i")
            self.emit(f"for (int {i} = 0; {i} < {n}; {i}++) {body(i)}")

    # --- a jaxpr --------------------------------------------------------------------------------------------
    def run(self, jaxpr, consts, args: list[Val]) -> list[Val]:
        """Emit ``jaxpr`` applied to ``args`` (with its ``consts``) and return its outputs."""
        env: dict = {}

        def read(a):
            if isinstance(a, jcore.Literal):
                val = np.asarray(a.val, dtype=a.aval.dtype)
                return Val(tuple(a.aval.shape), np.dtype(a.aval.dtype), const=val)
            return env[a]

        for var, c in zip(jaxpr.constvars, consts, strict=True):
            env[var] = Val(tuple(var.aval.shape), np.dtype(var.aval.dtype), const=np.asarray(c))
        for var, a in zip(jaxpr.invars, args, strict=True):
            env[var] = a
        for eqn in jaxpr.eqns:
            ins = [read(a) for a in eqn.invars]
            leaf = eqn.primitive.name not in CALLS and eqn.primitive.name not in CONTROL \
                and eqn.primitive.name != "custom_linear_solve"
            if leaf:
                self.begin()
            self.within.append(eqn)
            try:
                outs = self.equation(eqn, ins)
            except UnsupportedPrimitive as e:
                e.frames.extend(eqn_frames(eqn))
                raise
            finally:
                self.within.pop()
                if leaf:
                    self.end()
            for var, o in zip(eqn.outvars, outs, strict=True):
                env[var] = o
        return [read(a) for a in jaxpr.outvars]

    def equation(self, eqn, ins: list[Val]) -> list[Val]:
        name, params = eqn.primitive.name, eqn.params
        avals = [(tuple(v.aval.shape), np.dtype(v.aval.dtype)) for v in eqn.outvars]
        if name in CALLS or name == "custom_linear_solve":
            jaxpr, consts, args = inlined(name, params, ins)
            if name in CALLS and self.calls.get(id(jaxpr), 0) >= 2 and jaxpr_size(jaxpr) >= self.function_min \
                    and not all(v.const is not None for v in args):
                return self.call(jaxpr, consts, args)
            return self.run(jaxpr, consts, args)
        if name == "while":
            return self.while_loop(params, ins)
        if name == "cond":
            return self.cond(params, ins)
        if name == "scan":
            return self.scan(params, ins)
        if name == "optimization_barrier":
            return list(ins)
        if name == "reduce_precision":
            own_precision(params, ins[0].dtype)
        if all(v.const is not None for v in ins):
            return self.fold(eqn, ins)
        if name == "gather" and ins[1].const is None:
            return [self.take(ins[0], ins[1], params, *avals[0])]
        if name == "sort":
            raise UnsupportedPrimitive("sort of values known only at run time")
        if name in STRUCTURAL:
            return self.structural(eqn, ins, avals)
        if name in REDUCE:
            return [self.reduce(REDUCE[name], ins[0], params["axes"], *avals[0])]
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], params["dimension_numbers"], *avals[0])]
        if name == "lu":
            return self.lu(ins[0], avals)
        if name == "triangular_solve":
            return [self.triangular_solve(ins[0], ins[1], params, *avals[0])]
        if name == "eigh":
            refuse_choice(eqn, self.within[:-1])
            return self.eigh(ins[0], params, avals)
        if name == "lu_pivots_to_permutation":
            return [self.pivots_to_permutation(ins[0], int(params["permutation_size"]), *avals[0])]
        if name == "integer_pow":
            return [self.integer_pow(ins[0], params["y"], *avals[0])]
        if name == "convert_element_type":
            return [self.convert(ins[0], *avals[0])]
        if name == "iota":
            return self.fold(eqn, ins)
        if name == "round" and int(params.get("rounding_method", 0)) == 1:
            return [self.elementwise("rint", ins, *avals[0])]
        if name in ("select_n", "clamp") or name in BINARY or name in FLOAT_BINARY or name in INT_BINARY \
                or name in BOOL_BINARY or name in FLOAT_UNARY or name in INT_UNARY or name in BOOL_UNARY:
            return [self.elementwise(name, ins, *avals[0])]
        raise UnsupportedPrimitive(f"primitive {name!r} has no C translation (supported: liemef.codegen.PRIMITIVES)")

    def count_calls(self, jaxpr) -> None:
        """Count, over ``jaxpr`` and everything it calls, how often each called jaxpr is called."""
        for eqn in jaxpr.eqns:
            for sub in subjaxprs(eqn.params):
                if eqn.primitive.name in CALLS:
                    self.calls[id(sub)] = self.calls.get(id(sub), 0) + 1
                    if self.calls[id(sub)] > 1:
                        continue
                self.count_calls(sub)

    def call(self, jaxpr, consts, args: list[Val]) -> list[Val]:
        """A call of the C function for ``jaxpr`` (emitted on its first call)."""
        if id(jaxpr) not in self.functions:
            fname = self.fresh("f")
            params = [Val(a.shape, a.dtype, name=self.fresh("a")) for a in args]
            saved = (self.lines, self.nodes, self._open, self.indent)
            self.lines, self.nodes, self._open, self.indent = [], [], None, 1
            outs = self.run(jaxpr, consts, params)
            out_names = [self.fresh("o") for _ in outs]
            for v, n in zip(outs, out_names, strict=True):
                self.begin(root=True)
                self.loop(v.size, lambda i, v=v, n=n: f"{n}[{i}] = {self.elem(v, i)};")
                self.end()
            body = self.live_lines(0)
            self.lines, self.nodes, self._open, self.indent = saved
            sig = [f"const {ctype(a.dtype)} *restrict {a.name}" for a in params] + \
                  [f"{ctype(v.aval.dtype)} *restrict {n}" for v, n in zip(jaxpr.outvars, out_names, strict=True)]
            used = "".join(f"    (void){a.name};\n" for a in params)
            self.function_texts.append(f"static void {fname}({', '.join(sig)})\n{{\n{used}" + "\n".join(body) + "\n}\n")
            self.functions[id(jaxpr)] = (fname, jaxpr)
        fname = self.functions[id(jaxpr)][0]
        self.begin()
        outs = [self.declare(tuple(v.aval.shape), v.aval.dtype) for v in jaxpr.outvars]
        refs = []
        for a in args:
            if a.const is not None:
                refs.append(self.table(np.asarray(a.const, a.dtype).ravel()))
            else:
                self._read(a.name)
                refs.append(a.name)
        self.emit(f"{fname}({', '.join(refs + [o.name for o in outs])});")
        self.end()
        # one node defines every output: later nodes read them by name
        return outs

    # --- constants ------------------------------------------------------------------------------------------
    def fold(self, eqn, ins: list[Val]) -> list[Val]:
        """Evaluate an equation whose inputs are all known, in Python (constant folding)."""
        xs = [np.asarray(v.const, v.dtype) for v in ins]
        outs = np_eval(eqn.primitive.name, eqn.params, xs, [v.aval.dtype for v in eqn.outvars])
        if outs is None:
            with jax.ensure_compile_time_eval():
                outs = eqn.primitive.bind(*xs, **eqn.params)
            outs = outs if eqn.primitive.multiple_results else [outs]
        return [Val(tuple(np.shape(o)), np.dtype(o.dtype), const=np.asarray(o)) for o in outs]

    # --- elementwise ----------------------------------------------------------------------------------------
    def elementwise(self, name: str, ins: list[Val], shape, dtype) -> Val:
        kind = ins[-1].dtype.kind if name == "select_n" else ins[0].dtype.kind
        if name == "select_n":
            def expr(es):
                if len(es) == 3 and ins[0].dtype == np.bool_:
                    return f"({es[0]}) ? ({es[2]}) : ({es[1]})"
                out = es[-1]
                for j in range(len(es) - 2, 0, -1):
                    out = f"({es[0]}) == {j - 1} ? ({es[j]}) : ({out})"
                return out
        elif name == "clamp":
            f = "lm_max" if kind == "f" else None

            def expr(es):
                if f:
                    return f"lm_min(lm_max({es[1]}, {es[0]}), {es[2]})"
                return f"(({es[1]}) < ({es[0]}) ? ({es[0]}) : (({es[1]}) > ({es[2]}) ? ({es[2]}) : ({es[1]})))"
        else:
            table = {"f": {**FLOAT_UNARY, **BINARY, **FLOAT_BINARY, **ROUND_EVEN},
                     "b": {**BOOL_UNARY, **BINARY, **BOOL_BINARY}}.get(
                         kind, {**INT_UNARY, **BINARY, **INT_BINARY})
            if name not in table:
                raise UnsupportedPrimitive(f"primitive {name!r} on {ins[0].dtype}")
            fmt = table[name]

            def expr(es):
                if kind in "iu" and name in ("div", "rem"):
                    return int_division(name, es[0], es[1], ins[0].dtype)
                if kind in "iu" and name == "shift_left":
                    return shift_left(es[0], es[1], ins[0].dtype)
                return fmt.format(a=es[0], b=es[1] if len(es) > 1 else "")
        ins = [self.broadcast(v, shape) for v in ins]
        out = self.declare(shape, dtype)
        cast = f"({ctype(dtype)})" if dtype == np.bool_ or name in ("select_n",) else ""
        self.loop(out.size, lambda i: f"{out.name}[{i}] = {cast}({expr([self.elem(v, i) for v in ins])});")
        return out

    def broadcast(self, v: Val, shape) -> Val:
        """``v`` broadcast to ``shape`` (NumPy's rules; size-1 operands are read at index 0 as they are)."""
        if v.size == 1 or tuple(v.shape) == tuple(shape):
            return v
        if v.const is not None:
            return Val(tuple(shape), v.dtype, const=np.broadcast_to(v.const, shape))
        ids = np.broadcast_to(np.arange(1, v.size + 1).reshape(v.shape), shape).ravel()
        return self.gather_ids(ids, [(0, 1, v)], shape, v.dtype)

    def integer_pow(self, x: Val, y: int, shape, dtype) -> Val:
        out = self.declare(shape, dtype)

        def body(i):
            a = self.elem(x, i)
            if y == 0:
                return f"{out.name}[{i}] = 1;"
            p = " * ".join([f"({a})"] * abs(y))
            return f"{out.name}[{i}] = " + (f"1.0 / ({p});" if y < 0 else f"{p};")
        self.loop(out.size, body)
        return out

    def convert(self, x: Val, shape, dtype) -> Val:
        if x.dtype == dtype:
            return x
        out = self.declare(shape, dtype)
        if dtype == np.bool_:
            self.loop(out.size, lambda i: f"{out.name}[{i}] = ({self.elem(x, i)}) != 0;")
        elif x.dtype.kind == "f" and np.dtype(dtype).kind in "iu":
            self.loop(out.size, lambda i: f"{out.name}[{i}] = {float_to_int(self.elem(x, i), dtype)};")
        else:
            self.loop(out.size, lambda i: f"{out.name}[{i}] = ({ctype(dtype)})({self.elem(x, i)});")
        return out

    # --- structure ------------------------------------------------------------------------------------------
    def structural(self, eqn, ins: list[Val], avals) -> list[Val]:
        """Run the primitive on element ids (:func:`element_ids`) and move the elements they name."""
        data, bases, outs, add_into = element_ids(eqn, ins)
        owners = [(j, bases[j], ins[j]) for j in data]
        results = []
        for k, (o, (shape, dtype)) in enumerate(zip(outs, avals, strict=True)):
            if k:  # one node per output, so that an unused part of a split is dropped
                self.end()
                self.begin()
            ids = o
            if add_into:
                results.append(self.scatter_add(ids, ins[0], ins[2], bases[2], shape, dtype))
                continue
            results.append(self.gather_ids(ids, owners, shape, dtype))
        return results

    def gather_ids(self, ids: np.ndarray, owners, shape, dtype) -> Val:
        """The array whose element i is the element ``ids[i]`` names (0: zero)."""
        src = []
        for idv in ids:
            if idv == 0:
                src.append((None, 0))
                continue
            for _, base, v in owners:
                if base <= idv < base + v.size:
                    src.append((v, int(idv - base)))
                    break
        # all from constants: a constant
        if all(v is None or v.const is not None for v, _ in src):
            vals = np.array([0 if v is None else np.asarray(v.const).ravel()[e] for v, e in src], dtype=dtype)
            return Val(tuple(shape), np.dtype(dtype), const=vals.reshape(shape))
        # one operand in its own order: an alias
        if len(owners) >= 1 and all(v is owners[0][2] for v, _ in src) and owners[0][2].size == len(src) \
                and all(e == k for k, (_, e) in enumerate(src)) and owners[0][2].dtype == dtype:
            v = owners[0][2]
            return Val(tuple(shape), v.dtype, name=v.name, const=v.const)
        out = self.declare(shape, dtype)
        n = len(src)
        single = len({id(v) for v, _ in src if v is not None}) == 1 and all(v is not None for v, _ in src)
        runs = self._runs(src)
        if single and len(runs) > self.table_limit:
            v = src[0][0]
            tab = self.table(np.array([e for _, e in src], dtype=np.int32))
            self.loop(n, lambda i: f"{out.name}[{i}] = {self.elem(v, f'{tab}[{i}]')};")
            return out
        for start, length, v, e0, step in runs:
            if length == 1:
                self.emit(f"{out.name}[{start}] = {self._src(v, e0)};")
            else:
                k = self.fresh("i")
                idx = f"{e0} + {k}" if step == 1 else f"{e0}"
                if v is None:
                    rhs = literal(0, dtype)
                elif v.const is not None:
                    rhs = self.elem(v, idx) if step == 1 else self.elem(v, e0)
                else:
                    rhs = self.elem(v, idx)
                self.emit(f"for (int {k} = 0; {k} < {length}; {k}++) {out.name}[{start} + {k}] = {rhs};")
        return out

    def _src(self, v, e) -> str:
        return literal(0, np.float64) if v is None else self.elem(v, e)

    @staticmethod
    def _runs(src):
        """Maximal runs of consecutive elements (step 1) or repeats (step 0) of one operand."""
        runs = []
        i = 0
        while i < len(src):
            v, e = src[i]
            j = i + 1
            step = None
            while j < len(src) and src[j][0] is v:
                s = src[j][1] - src[j - 1][1]
                if step is None and s in (0, 1):
                    step = s
                if s != step:
                    break
                j += 1
            runs.append((i, j - i, v, e, 1 if step is None else step))
            i = j
        return runs

    def take(self, x: Val, idx: Val, params, shape, dtype) -> Val:
        """A gather with indices known at run time along one axis (:func:`take_layout`), clamped into range as
        XLA does: tables give each output element's base offset and index element."""
        a, places = take_layout(params, x.shape, idx.shape, shape)
        strides = np.cumprod((1,) + tuple(x.shape)[::-1])[::-1][1:]
        bshape = idx.shape[:-1]
        base = np.array([int(np.dot(src, strides)) if src else 0 for src, _ in places], np.int64)
        bidx = np.array([int(np.ravel_multi_index(b, bshape)) if bshape else 0 for _, b in places], np.int64)
        out = self.declare(shape, dtype)
        tb, ti = self.table(base.astype(np.int32)), self.table(bidx.astype(np.int32))
        o, r = self.fresh("i"), self.fresh("r")
        hi = x.shape[a] - 1
        self.emit(f"for (int {o} = 0; {o} < {out.size}; {o}++) {{")
        self.emit(f"    int {r} = (int)({self.elem(idx, f'{ti}[{o}]')});")
        if index_mode(params) == "fill":  # out of range: the fill value (NaN for floats), as XLA's FILL_OR_DROP
            fill = literal(fill_value(params.get("fill_value"), dtype), dtype)
            self.emit(f"    if ({r} < 0 || {r} > {hi}) {{ {out.name}[{o}] = {fill}; continue; }}")
        self.emit(f"    {r} = {r} < 0 ? 0 : ({r} > {hi} ? {hi} : {r});")
        self.emit(f"    {out.name}[{o}] = {self.elem(x, f'{tb}[{o}] + {r} * {int(strides[a])}')};")
        self.emit("}")
        return out

    def scatter_add(self, ids, operand: Val, updates: Val, base: int, shape, dtype) -> Val:
        out = self.declare(shape, dtype)
        self.loop(out.size, lambda i: f"{out.name}[{i}] = {self.elem(operand, i)};")
        for i, idv in enumerate(ids):
            if idv >= base and idv < base + updates.size:
                self.emit(f"{out.name}[{i}] += {self.elem(updates, int(idv - base))};")
        return out

    # --- reductions and products ----------------------------------------------------------------------------
    def reduce(self, op: str, x: Val, axes, shape, dtype) -> Val:
        axes = tuple(int(a) for a in axes)
        keep = [d for d in range(len(x.shape)) if d not in axes]
        n_out = int(np.prod(shape, dtype=np.int64))
        idx = np.arange(x.size).reshape(x.shape).transpose(keep + list(axes)).reshape(n_out, -1)
        out = self.declare(shape, dtype)
        R = idx.shape[1]
        combine = {"sum": "{acc} + {x}", "prod": "{acc} * {x}", "and": "{acc} && {x}", "or": "{acc} || {x}",
                   "max": "lm_max({acc}, {x})" if x.dtype.kind == "f" else "({acc} > {x} ? {acc} : {x})",
                   "min": "lm_min({acc}, {x})" if x.dtype.kind == "f" else "({acc} < {x} ? {acc} : {x})"}
        if op in ("argmax", "argmin"):
            raise UnsupportedPrimitive(f"{op} of values known only at run time")
        fmt = combine[op]
        # XLA's sum of two terms or more starts from +0 (it is never -0): +0 + the first term
        first = "0.0 + " if op == "sum" and x.dtype.kind == "f" and R >= 2 else ""
        contiguous = (idx == idx[:, :1] + np.arange(R)).all()
        if R == 0:
            init = {"sum": 0, "prod": 1, "and": 1, "or": 0, "max": -np.inf, "min": np.inf}[op]
            self.loop(out.size, lambda i: f"{out.name}[{i}] = {literal(init, dtype)};")
            return out
        if contiguous and out.size == 1:
            acc = f"{out.name}[0]"
            self.emit(f"{acc} = {first}{self.elem(x, int(idx[0, 0]))};")
            if R > 1:
                k = self.fresh("i")
                nxt = fmt.format(acc=acc, x=self.elem(x, f"{int(idx[0, 0])} + {k}"))
                self.emit(f"for (int {k} = 1; {k} < {R}; {k}++) {acc} = {nxt};")
            return out
        if out.size * R <= 16:
            for o in range(out.size):
                acc = f"{out.name}[{o}]"
                self.emit(f"{acc} = {first}{self.elem(x, int(idx[o, 0]))};")
                for r in range(1, R):
                    self.emit(f"{acc} = {fmt.format(acc=acc, x=self.elem(x, int(idx[o, r])))};")
            return out
        tab = self.table(idx.astype(np.int32).ravel())
        o, k = self.fresh("i"), self.fresh("i")
        acc = f"{out.name}[{o}]"
        self.emit(f"for (int {o} = 0; {o} < {out.size}; {o}++) {{")
        self.emit(f"    {acc} = {first}{self.elem(x, f'{tab}[{o} * {R}]')};")
        self.emit(f"    for (int {k} = 1; {k} < {R}; {k}++) {acc} = "
                  f"{fmt.format(acc=acc, x=self.elem(x, f'{tab}[{o} * {R} + {k}]'))};")
        self.emit("}")
        return out

    def dot_general(self, a: Val, b: Val, dims, shape, dtype) -> Val:
        (ca, cb), (ba, bb) = dims
        ca, cb, ba, bb = (tuple(int(d) for d in t) for t in (ca, cb, ba, bb))
        fa = [d for d in range(len(a.shape)) if d not in ca and d not in ba]
        fb = [d for d in range(len(b.shape)) if d not in cb and d not in bb]
        sa = np.cumprod((1,) + a.shape[::-1])[::-1][1:] if a.shape else ()
        sb = np.cumprod((1,) + b.shape[::-1])[::-1][1:] if b.shape else ()
        out = self.declare(shape, dtype)
        so = np.cumprod((1,) + tuple(shape)[::-1])[::-1][1:] if shape else ()
        # output axes: batch, free of a, free of b
        loops, ia, ib, io = [], [], [], []
        for k, (da, db) in enumerate(zip(ba, bb, strict=True)):
            v = self.fresh("i")
            loops.append((v, a.shape[da]))
            ia.append(f"{v} * {sa[da]}")
            ib.append(f"{v} * {sb[db]}")
            io.append(f"{v} * {so[k]}")
        k0 = len(ba)
        for k, d in enumerate(fa):
            v = self.fresh("i")
            loops.append((v, a.shape[d]))
            ia.append(f"{v} * {sa[d]}")
            io.append(f"{v} * {so[k0 + k]}")
        k0 += len(fa)
        for k, d in enumerate(fb):
            v = self.fresh("i")
            loops.append((v, b.shape[d]))
            ib.append(f"{v} * {sb[d]}")
            io.append(f"{v} * {so[k0 + k]}")
        cl, ca_i, cb_i = [], [], []
        for da, db in zip(ca, cb, strict=True):
            v = self.fresh("i")
            cl.append((v, a.shape[da]))
            ca_i.append(f"{v} * {sa[da]}")
            cb_i.append(f"{v} * {sb[db]}")
        join = lambda xs: " + ".join(xs) if xs else "0"  # noqa: E731
        opened = 0
        for v, n in loops:
            self.emit(f"for (int {v} = 0; {v} < {n}; {v}++) {{")
            self.indent += 1
            opened += 1
        acc = self.fresh("s")
        # from +0, as XLA's dot (never -0); a contraction of one term is XLA's product: from -0, which adds nothing
        one_term = int(np.prod([a.shape[d] for d in ca], dtype=np.int64)) == 1 and np.dtype(dtype).kind == "f"
        self.emit(f"{ctype(dtype)} {acc} = {'-0.0' if one_term else '0'};")
        for v, n in cl:
            self.emit(f"for (int {v} = 0; {v} < {n}; {v}++) {{")
            self.indent += 1
        self.emit(f"{acc} += {self.elem(a, join(ia + ca_i))} * {self.elem(b, join(ib + cb_i))};")
        for _ in cl:
            self.indent -= 1
            self.emit("}")
        self.emit(f"{out.name}[{join(io)}] = {acc};")
        for _ in range(opened):
            self.indent -= 1
            self.emit("}")
        return out

    # --- linear algebra -------------------------------------------------------------------------------------
    def lu(self, a: Val, avals) -> list[Val]:
        """LU with partial pivoting as XLA's ``getrf`` (SciPy's OpenBLAS) computes it, column by column
        (left-looking): each entry's dot product with the factors before it first, subtracted once (rounding and
        the sign of an exact zero as there; subtracting term by term gave other ones); the pivot the first
        largest |.|, a NaN never chosen over a number; the column below it times the pivot's reciprocal, which
        BLAS's scaling by 0 (an infinite pivot) makes 0, not NaN. Returns ``lu``, ``pivots`` (row swapped with
        row i at step i) and the ``permutation``."""
        if len(a.shape) != 2 or a.shape[0] != a.shape[1]:
            raise UnsupportedPrimitive(f"lu of shape {a.shape} (only square, unbatched)")
        n = a.shape[0]
        lu = self.declare(*avals[0])
        piv = self.declare(*avals[1])
        perm = self.declare(*avals[2])
        self.loop(n * n, lambda i: f"{lu.name}[{i}] = {self.elem(a, i)};")
        self.loop(n, lambda i: f"{perm.name}[{i}] = {i};")
        self.emit(f"(void){piv.name}; (void){perm.name};")
        k, i, j, p, s = self.fresh("i"), self.fresh("i"), self.fresh("i"), self.fresh("p"), self.fresh("s")
        L = lu.name
        self.emit(f"for (int {k} = 0; {k} < {n}; {k}++) {{")
        self.emit(f"    for (int {i} = 1; {i} < {n}; {i}++) {{")
        self.emit(f"        const int {p} = {i} < {k} ? {i} : {k};")
        self.emit(f"        double {s} = -0.0;")
        self.emit(f"        if ({p} == 0) continue;")
        self.emit(f"        for (int {j} = 0; {j} < {p}; {j}++) {s} += {L}[{i} * {n} + {j}] * {L}[{j} * {n} + {k}];")
        self.emit(f"        {L}[{i} * {n} + {k}] -= {s};")
        self.emit("    }")
        self.emit(f"    int {p} = {k};")
        self.emit(f"    for (int {i} = {k} + 1; {i} < {n}; {i}++) if (fabs({L}[{i} * {n} + {k}]) > "
                  f"fabs({L}[{p} * {n} + {k}]) || {L}[{p} * {n} + {k}] != {L}[{p} * {n} + {k}]) {p} = {i};")
        self.emit(f"    {piv.name}[{k}] = {p};")
        self.emit(f"    if ({p} != {k}) {{")
        self.emit(f"        for (int {j} = 0; {j} < {n}; {j}++) {{ double t = {L}[{k} * {n} + {j}]; "
                  f"{L}[{k} * {n} + {j}] = {L}[{p} * {n} + {j}]; {L}[{p} * {n} + {j}] = t; }}")
        self.emit(f"        {{ int32_t t = {perm.name}[{k}]; {perm.name}[{k}] = {perm.name}[{p}]; "
                  f"{perm.name}[{p}] = t; }}")
        self.emit("    }")
        self.emit(f"    if ({L}[{k} * {n} + {k}] != 0.0) {{")
        self.emit(f"        const double {s} = 1.0 / {L}[{k} * {n} + {k}];")
        self.emit(f"        for (int {i} = {k} + 1; {i} < {n}; {i}++) "
                  f"{L}[{i} * {n} + {k}] = {s} == 0.0 ? 0.0 : {L}[{i} * {n} + {k}] * {s};")
        self.emit("    }")
        self.emit("}")
        return [lu, piv, perm]

    def pivots_to_permutation(self, piv: Val, m: int, shape, dtype) -> Val:
        """The permutation of LU's row swaps (``pivots[..., i]``: the row swapped with row i at step i) over
        ``m`` rows, as ``lax.linalg.lu_pivots_to_permutation`` (``jax.scipy.linalg.lu_solve`` applies it).
        A pivot out of [0, m) (never from an LU) is clamped, so that no write leaves the array."""
        k = piv.shape[-1]
        batch = piv.size // max(k, 1)
        out = self.declare(shape, dtype)
        b, i, j, t = self.fresh("i"), self.fresh("i"), self.fresh("j"), self.fresh("t")
        P = lambda r: f"{out.name}[{b} * {m} + {r}]"  # noqa: E731
        self.emit(f"for (int {b} = 0; {b} < {batch}; {b}++) {{")
        self.emit(f"    for (int {i} = 0; {i} < {m}; {i}++) {P(i)} = {i};")
        self.emit(f"    for (int {i} = 0; {i} < {k}; {i}++) {{")
        self.emit(f"        int32_t {j} = (int32_t){self.elem(piv, f'{b} * {k} + {i}')};")
        self.emit(f"        if ({j} < 0) {j} = 0;")
        self.emit(f"        if ({j} > {m - 1}) {j} = {m - 1};")
        self.emit(f"        {{ const int32_t {t} = {P(i)}; {P(i)} = {P(j)}; {P(j)} = {t}; }}")
        self.emit("    }")
        self.emit("}")
        return out

    def eigh(self, a: Val, params, avals) -> list[Val]:
        """The symmetric eigendecomposition (``v``, ``w``: eigenvectors as columns, eigenvalues ascending) of
        the triangle ``lower`` (or upper) of ``a``, by cyclic Jacobi rotations (Golub & Van Loan, Algorithm
        8.5.3) until the off-diagonal part is below the rounding of the whole. Not LAPACK's algorithm: the
        eigenvalues agree to rounding, an eigenvector up to its sign (and, for a repeated eigenvalue, up to a
        rotation of its eigenspace). Hence for liemef's own use alone, where that choice does not matter
        (:func:`refuse_choice`)."""
        if len(a.shape) != 2 or a.shape[0] != a.shape[1] or a.dtype != np.float64:
            raise UnsupportedPrimitive(f"eigh of shape {a.shape} and dtype {a.dtype} (only square float64, "
                                       "unbatched)")
        if params.get("subset_by_index") not in (None, (0, a.shape[0])) or not params.get("sort_eigenvalues", True):
            raise UnsupportedPrimitive("eigh of a subset of eigenvalues or unsorted")
        n = a.shape[0]
        v, w = self.declare(*avals[0]), self.declare(*avals[1])
        A, i, j, k, p, q, sweep = (self.fresh(x) for x in ("A", "i", "i", "i", "i", "i", "i"))
        lower = bool(params.get("lower", True))
        tri = (lambda r, c: f"({r} >= {c} ? {r} * {n} + {c} : {c} * {n} + {r})") if lower else \
            (lambda r, c: f"({r} <= {c} ? {r} * {n} + {c} : {c} * {n} + {r})")
        V = v.name
        self.emit(f"double {A}[{n * n}];")
        self.emit(f"for (int {i} = 0; {i} < {n}; {i}++) for (int {j} = 0; {j} < {n}; {j}++) {{ "
                  f"{A}[{i} * {n} + {j}] = {self.elem(a, tri(i, j))}; {V}[{i} * {n} + {j}] = {i} == {j}; }}")
        self.emit(f"for (int {sweep} = 0; {sweep} < 64; {sweep}++) {{")
        self.emit("    double joff = 0.0, jall = 0.0;")
        self.emit(f"    for (int {i} = 0; {i} < {n}; {i}++) for (int {j} = 0; {j} < {n}; {j}++) {{ "
                  f"double je = {A}[{i} * {n} + {j}] * {A}[{i} * {n} + {j}]; jall += je; "
                  f"if ({i} != {j}) joff += je; }}")
        self.emit("    if (!(joff > 4.93e-32 * jall)) break;  /* converged (or not finite) */")
        self.emit(f"    for (int {p} = 0; {p} < {n}; {p}++) for (int {q} = {p} + 1; {q} < {n}; {q}++) {{")
        self.emit(f"        const double japq = {A}[{p} * {n} + {q}];")
        self.emit("        if (japq == 0.0) continue;")
        self.emit(f"        const double jtau = ({A}[{q} * {n} + {q}] - {A}[{p} * {n} + {p}]) / (2.0 * japq);")
        self.emit("        const double jt = (jtau >= 0.0 ? 1.0 : -1.0) / (fabs(jtau) + sqrt(1.0 + jtau * jtau));")
        self.emit("        const double jc = 1.0 / sqrt(1.0 + jt * jt), js = jt * jc;")
        for M, columns in ((A, True), (A, False), (V, True)):
            # columns p, q of A (A J), then its rows p, q (J^T A J), then the columns of V (V J)
            at = (lambda x, M=M: f"{M}[{k} * {n} + {x}]") if columns else (lambda x, M=M: f"{M}[{x} * {n} + {k}]")
            self.emit(f"        for (int {k} = 0; {k} < {n}; {k}++) {{ const double jx = {at(p)}, "
                      f"jy = {at(q)}; {at(p)} = jc * jx - js * jy; {at(q)} = js * jx + jc * jy; }}")
        self.emit(f"        {A}[{p} * {n} + {q}] = 0.0; {A}[{q} * {n} + {p}] = 0.0;")
        self.emit("    }")
        self.emit("}")
        # ascending eigenvalues, their vectors with them (selection sort)
        self.emit(f"for (int {i} = 0; {i} < {n}; {i}++) {w.name}[{i}] = {A}[{i} * {n} + {i}];")
        self.emit(f"for (int {i} = 0; {i} < {n}; {i}++) {{")
        self.emit(f"    int {p} = {i};")
        self.emit(f"    for (int {j} = {i} + 1; {j} < {n}; {j}++) if ({w.name}[{j}] < {w.name}[{p}]) {p} = {j};")
        self.emit(f"    if ({p} != {i}) {{")
        self.emit(f"        const double jx = {w.name}[{i}]; {w.name}[{i}] = {w.name}[{p}]; {w.name}[{p}] = jx;")
        self.emit(f"        for (int {k} = 0; {k} < {n}; {k}++) {{ const double jy = {V}[{k} * {n} + {i}]; "
                  f"{V}[{k} * {n} + {i}] = {V}[{k} * {n} + {p}]; {V}[{k} * {n} + {p}] = jy; }}")
        self.emit("    }")
        self.emit("}")
        return [v, w]

    def triangular_solve(self, a: Val, b: Val, params, shape, dtype) -> Val:
        """op(A) X = B (``left_side``) or X op(A) = B, A triangular (m x m), unbatched."""
        if len(a.shape) != 2 or len(b.shape) != 2:
            raise UnsupportedPrimitive("triangular_solve with batch axes")
        m = a.shape[0]
        lower, trans, unit = bool(params["lower"]), bool(params["transpose_a"]), bool(params["unit_diagonal"])
        left = bool(params["left_side"])
        out = self.declare(shape, dtype)
        # X op(A) = B  <=>  op(A)^T X^T = B^T: solve columns of B (left) or rows of B (right)
        eff_lower = lower != trans if left else lower == trans
        # element (r, c) of the effective left matrix T (T X = B): A or A^T
        if left:
            T = (lambda r, c: self.elem(a, f"({c}) * {m} + ({r})")) if trans else \
                (lambda r, c: self.elem(a, f"({r}) * {m} + ({c})"))
            cols = b.shape[1]
            X = lambda r, c: f"{out.name}[({r}) * {cols} + ({c})]"  # noqa: E731
        else:
            T = (lambda r, c: self.elem(a, f"({r}) * {m} + ({c})")) if trans else \
                (lambda r, c: self.elem(a, f"({c}) * {m} + ({r})"))
            cols = b.shape[0]
            X = lambda r, c: f"{out.name}[({c}) * {m} + ({r})]"  # noqa: E731
        self.loop(out.size, lambda i: f"{out.name}[{i}] = {self.elem(b, i)};")
        # as BLAS's dtrsm (XLA calls LAPACK's): each unknown's dot product with the solved ones first (from its
        # first product: -0 + p is p), subtracted once, then times the diagonal's reciprocal (subtracting term
        # by term gave another sign to an exact zero: -0 - (-0) - (+0) is +0, -0 - (-0 + +0) is -0)
        c, r, k, s = self.fresh("i"), self.fresh("i"), self.fresh("i"), self.fresh("s")
        self.emit(f"for (int {c} = 0; {c} < {cols}; {c}++) {{")
        if eff_lower:
            self.emit(f"    for (int {r} = 0; {r} < {m}; {r}++) {{")
            self.emit(f"        double {s} = -0.0;")
            self.emit(f"        for (int {k} = 0; {k} < {r}; {k}++) {s} += {T(r, k)} * {X(k, c)};")
        else:
            self.emit(f"    for (int {r} = {m} - 1; {r} >= 0; {r}--) {{")
            self.emit(f"        double {s} = -0.0;")
            self.emit(f"        for (int {k} = {r} + 1; {k} < {m}; {k}++) {s} += {T(r, k)} * {X(k, c)};")
        self.emit(f"        if ({r} != {0 if eff_lower else m - 1}) {X(r, c)} -= {s};")
        if not unit:
            self.emit(f"        {X(r, c)} *= 1.0 / {T(r, r)};")
        self.emit("    }")
        self.emit("}")
        return out

    # --- control flow ---------------------------------------------------------------------------------------
    def _materialize(self, v: Val) -> Val:
        """A fresh array holding ``v``'s value (the carry of a loop must be a variable)."""
        opened = self._open is None
        if opened:
            self.begin()
        out = self.declare(v.shape, v.dtype)
        self.loop(out.size, lambda i: f"{out.name}[{i}] = {self.elem(v, i)};")
        if opened:
            self.end()
        return out

    def while_loop(self, params, ins: list[Val]) -> list[Val]:
        nc, nb = params["cond_nconsts"], params["body_nconsts"]
        cconsts, bconsts, init = ins[:nc], ins[nc:nc + nb], ins[nc + nb:]
        carry = [self._materialize(v) for v in init]
        pred = self.fresh("p")
        self.emit("for (;;) {")
        self.indent += 1
        self.emit(f"_Bool {pred};")
        self.emit("{")
        self.indent += 1
        (c,) = self.run(params["cond_jaxpr"].jaxpr, params["cond_jaxpr"].consts, cconsts + carry)
        self.begin(root=True)
        self.emit(f"{pred} = {self.elem(c, 0)};")
        self.end()
        self.indent -= 1
        self.emit("}")
        self.emit(f"if (!{pred}) break;")
        self.emit("{")
        self.indent += 1
        new = self.run(params["body_jaxpr"].jaxpr, params["body_jaxpr"].consts, bconsts + carry)
        self.assign(carry, new)
        self.indent -= 1
        self.emit("}")
        self.indent -= 1
        self.emit("}")
        return carry

    def scan(self, params, ins: list[Val]) -> list[Val]:
        """A ``scan`` with neither inputs nor outputs per iteration (``fori_loop``'s form): a counted C loop."""
        nc, ncar, length = params["num_consts"], params["num_carry"], int(params["length"])
        jaxpr = params["jaxpr"]
        if len(ins) != nc + ncar or len(jaxpr.jaxpr.outvars) != ncar:
            raise UnsupportedPrimitive("scan with per-iteration inputs or outputs (only fori_loop's form)")
        carry = [self._materialize(v) for v in ins[nc:]]
        it = self.fresh("it")
        self.emit(f"for (int {it} = 0; {it} < {length}; {it}++) {{")
        self.indent += 1
        new = self.run(jaxpr.jaxpr, jaxpr.consts, ins[:nc] + carry)
        self.assign(carry, new)
        self.indent -= 1
        self.emit("}")
        return carry

    def assign(self, targets: list[Val], values: list[Val]) -> None:
        """targets[j] = values[j] for all j at once (a value may be another target: copied through a temporary)."""
        names = {t.name for t in targets}
        staged = []
        for t, v in zip(targets, values, strict=True):
            if v.const is None and v.name == t.name:
                staged.append(None)
            elif v.const is None and v.name in names:
                staged.append(self._materialize(v))
            else:
                staged.append(v)
        for t, v in zip(targets, staged, strict=True):
            if v is not None:
                self.begin()
                self._open[2].add(t.name)
                self.loop(t.size, lambda i, t=t, v=v: f"{t.name}[{i}] = {self.elem(v, i)};")
                self.end()

    def cond(self, params, ins: list[Val]) -> list[Val]:
        index, ops = ins[0], ins[1:]
        branches = params["branches"]
        outs = []
        for v in branches[0].jaxpr.outvars:
            self.begin()
            outs.append(self.declare(tuple(v.aval.shape), v.aval.dtype))
            self.end()
        self.begin(root=True)
        self.emit(f"switch ((int)({self.elem(index, 0)})) {{")
        self.end()
        for j, br in enumerate(branches):
            self.emit("default: {" if j == len(branches) - 1 else f"case {j}: {{")
            self.indent += 1
            res = self.run(br.jaxpr, br.consts, ops)
            self.assign(outs, res)
            self.emit("break;")
            self.indent -= 1
            self.emit("}")
        self.emit("}")
        return outs


def jaxpr_to_c(name: str, closed_jaxpr, arg_names: list[str], out_names: list[str], *,
               translator: Translator | None = None) -> tuple[str, Translator]:
    """A C function ``void name(const T *arg..., T *out...)`` computing ``closed_jaxpr`` on flat row-major
    arrays. Returns its text (tables are in ``translator.table_lines``, emitted once per source)."""
    tr = translator or Translator()
    jaxpr = closed_jaxpr.jaxpr
    tr.count_calls(jaxpr)
    args = [Val(tuple(v.aval.shape), np.dtype(v.aval.dtype), name=n)
            for v, n in zip(jaxpr.invars, arg_names, strict=True)]
    start = len(tr.lines)
    tr.indent = 1
    outs = tr.run(jaxpr, closed_jaxpr.consts, args)
    for v, n in zip(outs, out_names, strict=True):
        tr.begin(root=True)
        tr.loop(v.size, lambda i, v=v, n=n: f"{n}[{i}] = {tr.elem(v, i)};")
        tr.end()
    body = tr.live_lines(start)
    del tr.lines[start:]
    tr.nodes = [nd for nd in tr.nodes if nd[0] < start]
    sig_in = [f"const {ctype(a.dtype)} *restrict {a.name}" for a in args]
    sig_out = [f"{ctype(v.aval.dtype)} *restrict {n}" for v, n in zip(jaxpr.outvars, out_names, strict=True)]
    text = f"static void {name}({', '.join(sig_in + sig_out)})\n{{\n" + "\n".join(body) + "\n}\n"
    return text, tr
