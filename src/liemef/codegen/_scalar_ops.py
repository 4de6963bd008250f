"""The scalar translator's primitives: elementwise, data movement, indexing and reductions (mixins of
:class:`~._scalar_c.ScalarTranslator`)."""

from __future__ import annotations

import numpy as np

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
    STRUCTURAL,
    UnsupportedPrimitive,
    Val,
    ctype,
    element_ids,
    fill_value,
    index_mode,
    inlined,
    literal,
    np_eval,
    own_precision,
    refuse_choice,
    take_layout,
)
from ._scalar_nodes import CUMULATIVE, LOOKUP_MIN, negative_zero


class Equations:
    """One equation's nodes: the elementwise primitives, selects and data movement
    (:class:`~._scalar_c.ScalarTranslator`'s part)."""

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


class Indexing:
    """Gathers, scatters, dynamic slices and takes, at known or run-time indices
    (:class:`~._scalar_c.ScalarTranslator`'s part)."""

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


class Reductions:
    """Reductions, argmax and argmin, sorts, cumulative sums, Cholesky and ``dot_general``
    (:class:`~._scalar_c.ScalarTranslator`'s part)."""

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
                if self.is_const(t) and self.cval(t) == 0 and (not real or init or negative_zero(self.cval(t))):
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
            out = not negative_zero(self.value[i]) if self.dtype[i].kind == "f" else True
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
