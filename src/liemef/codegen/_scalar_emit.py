"""The scalar translator's control flow and its writing of C (mixins of
:class:`~._scalar_c.ScalarTranslator`)."""

from __future__ import annotations

import numpy as np

from ._jaxpr_c import Translator
from ._primitives import (
    UnsupportedPrimitive,
    Val,
    ctype,
    jaxpr_size,
)
from ._scalar_nodes import LANE_SUFFIX, UNROLL_MAX, Scope, lane_type


class ControlFlow:
    """Blocks of the array translator, ``while``, ``scan`` and ``cond``
    (:class:`~._scalar_c.ScalarTranslator`'s part)."""

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


class Emission:
    """Writing the graph as C: live nodes, statements, scalar or lane code
    (:class:`~._scalar_c.ScalarTranslator`'s part)."""

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
