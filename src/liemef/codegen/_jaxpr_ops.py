"""The array translator's primitives: elementwise, data movement and indexing, and the reductions and
linear algebra (mixins of :class:`~._jaxpr_c.Translator`)."""

from __future__ import annotations

import numpy as np

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
    Val,
    ctype,
    element_ids,
    fill_value,
    float_to_int,
    index_mode,
    int_division,
    literal,
    shift_left,
    take_layout,
)


class ArrayElementwise:
    """Elementwise primitives, broadcasts, conversions, data movement, gathers and scatters as C loops
    (:class:`~._jaxpr_c.Translator`'s part)."""

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


class ArrayLinearAlgebra:
    """Reductions, ``dot_general``, LU, pivots, ``eigh`` and triangular solves as C loops
    (:class:`~._jaxpr_c.Translator`'s part)."""

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
