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

from ._jaxpr_ops import ArrayElementwise, ArrayLinearAlgebra
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
    STRUCTURAL,
    UnsupportedPrimitive,
    Val,
    ctype,
    inlined,
    jaxpr_size,
    literal,
    np_eval,
    own_precision,
    refuse_choice,
    subjaxprs,
    translating,
)


class Translator(ArrayElementwise, ArrayLinearAlgebra):
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
            try:
                with translating(self.within, eqn):
                    outs = self.equation(eqn, ins)
            finally:
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
