"""A filter run's status, carried through the compiled loop: failures are values, never raised inside ``jit``.

A run (or an online step) is healthy until one sample interval produces a state that is non-finite, a gain K
that cannot stay symmetric (where the connection makes it symmetric, the minimum-energy filter checks
that E is) or no longer positive definite, beyond a
tolerance, or a sensor whose samples a gate has rejected too many times in a row. The first such interval is
recorded (its index, its start time and the cause); the state is then frozen at the last good one, and the
status with it: its counters describe the run up to and including the failing interval.
"""

from __future__ import annotations

import enum
import math
import operator

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._times import seconds, time_said

SYMMETRY_TOL = 1e-8
"""Largest relative asymmetry ``max|K - K^T| / max(1, max|K|)`` of a gain that should be symmetric."""
DEFINITE_TOL = 1e-9
"""K counts as positive definite while ``sym(K) + DEFINITE_TOL * max|K| I`` has a Cholesky factor."""


class _Enumeration(enum.EnumType):
    """The metaclass of :data:`CAUSES`: its members are read by name (``CAUSES.NONFINITE``) and, as a status
    code indexes them, by code (``CAUSES[code]``, a Python, NumPy or 0-d JAX integer)."""

    def __getitem__(cls, key):
        if isinstance(key, str):
            return super().__getitem__(key)
        return tuple(cls)[operator.index(key)]  # the members in the order of their codes


class _ClassMethodOnClass:
    """A method that is a classmethod when read off the class and the ``str`` method of the same name when read
    off a member (a member of :data:`CAUSES` is a string)."""

    def __init__(self, fn):
        self.fn = fn

    def __get__(self, obj, cls=None):
        if obj is None:
            return self.fn.__get__(cls, type(cls))
        return getattr(str, self.fn.__name__).__get__(obj, cls)


class CAUSES(enum.StrEnum, metaclass=_Enumeration):
    """Why a run failed, one member per cause with its message (the shape of diffrax's ``RESULTS``).

    A member is its label (a string: ``CAUSES.NONFINITE == "non-finite"``, as tables and JSON write it),
    ``code`` is its number in :attr:`Status.code` (``CAUSES[code]`` is the member of a code) and ``message``
    says what happened, for :meth:`Status.message`.
    """

    OK = 0, "ok", "ok"
    NONFINITE = 1, "non-finite", "the state or the gain K became non-finite (NaN or inf)"
    ASYMMETRIC = 2, "K not symmetric", f"the gain K lost its symmetry (beyond {SYMMETRY_TOL:g} relative)"
    INDEFINITE = 3, "K not positive definite", "the gain K lost positive definiteness"
    GATE = 4, "gate", "a sensor's gate rejected more consecutive samples than its max_rejections"
    NOT_CONVERGED = 5, "not converged", ("the smoother over the whole log did not converge (its iterations ran out, or "
                                         "no step lowered its cost; liemef.smoothers)")

    @_ClassMethodOnClass
    def index(cls, label: str) -> int:
        """The code of the cause labelled ``label`` (``CAUSES.index("non-finite") == 1``, as on the tuple of labels
        CAUSES once was); on a member, ``str.index``."""
        return cls(label).code

    def __new__(cls, code: int, label: str, message: str):
        member = str.__new__(cls, label)
        member._value_ = label
        member.code = code
        member.message = message
        return member


FILTER_CAUSES = tuple(c for c in CAUSES if c is not CAUSES.NOT_CONVERGED)
"""The causes a filter's interval can produce (an exported C filter's status codes): all but the smoother's."""


class Status(eqx.Module):
    """Health and counters of a run, all array leaves (batched under ``vmap``).

    ``code`` is 0 while healthy, else the ``code`` of its cause in :data:`CAUSES`; ``index`` and ``time`` are
    the first bad sample interval ``[ts[index], ts[index + 1]]`` and its start (-1 and NaN while healthy).
    ``rejected[b]`` counts the samples of sensor block ``b`` rejected by its gate, ``consecutive[b]`` the
    current run of rejections. ``substeps_max``/``substeps_total`` count the integration sub-steps,
    ``substeps_capped`` the intervals that needed more than ``max_substeps``. ``gaps`` counts the intervals
    longer than the gap threshold (predicted through, density sensors not held), ``longest_gap`` the longest
    interval, ``inputs_held`` the input samples that were missing (the last input was held).
    """

    code: Int[Array, ""]
    index: Int[Array, ""]
    time: Float[Array, ""]
    steps: Int[Array, ""]
    rejected: Int[Array, " b"]
    consecutive: Int[Array, " b"]
    substeps_max: Int[Array, ""]
    substeps_total: Int[Array, ""]
    substeps_capped: Int[Array, ""]
    gaps: Int[Array, ""]
    longest_gap: Float[Array, ""]
    inputs_held: Int[Array, ""]

    @staticmethod
    def initial(n_blocks: int) -> Status:
        """A healthy status before the first interval."""
        i = lambda: jnp.zeros((), jnp.int32)  # noqa: E731
        return Status(code=i(), index=jnp.asarray(-1, jnp.int32), time=jnp.asarray(jnp.nan, jnp.float64), steps=i(),
                      rejected=jnp.zeros((n_blocks,), jnp.int32), consecutive=jnp.zeros((n_blocks,), jnp.int32),
                      substeps_max=i(), substeps_total=i(), substeps_capped=i(), gaps=i(),
                      longest_gap=jnp.asarray(0.0, jnp.float64), inputs_held=i())

    @property
    def ok(self) -> bool:
        """True if no interval failed (a Python bool; use ``status.code == 0`` under ``vmap``)."""
        return bool(np.all(np.asarray(self.code) == CAUSES.OK.code))

    @property
    def cause(self) -> str:
        """The cause's label (a single run)."""
        return CAUSES[int(self.code)].value

    def as_dict(self, block_names=None) -> dict:
        """The status of a single run as plain Python values (JSON)."""
        names = block_names or [f"block{b}" for b in range(np.asarray(self.rejected).shape[0])]
        t = float(self.time)
        return {"ok": self.ok, "cause": self.cause, "index": int(self.index) if not self.ok else None,
                "time": t if math.isfinite(t) else None, "steps": int(self.steps),
                "rejected": {n: int(r) for n, r in zip(names, np.asarray(self.rejected), strict=True)},
                "substeps_max": int(self.substeps_max), "substeps_total": int(self.substeps_total),
                "substeps_capped": int(self.substeps_capped), "gaps": int(self.gaps),
                "longest_gap": float(self.longest_gap), "inputs_held": int(self.inputs_held)}

    def message(self, ts=None) -> str:
        """One line saying where, when (from the start ``ts[0]`` of the log, :func:`liemef._times.time_said`) and
        why a single run failed ("ok" if it did not)."""
        if self.ok:
            return "ok"
        k = int(self.index)
        t0 = 0.0 if ts is None else float(ts[0])
        if ts is not None and k + 1 < len(ts):
            a, b = float(ts[k]) - t0, float(ts[k + 1]) - t0
            span = f"[{a:.6g}, {b:.6g}] s" if t0 == 0.0 else f"[t0 + {a:.6g}, t0 + {b:.6g}] s, t0 = {seconds(t0)} s"
        else:
            span = time_said(float(self.time), t0)
        why = CAUSES[int(self.code)].message
        return (f"filter failed over the sample interval {k} ({span}): {why}; the last good state is the one at "
                f"sample {k}")


def positive_definite(S: Float[Array, "n n"]) -> Bool[Array, ""]:
    """Whether the symmetric ``S`` has a Cholesky factor, by an unrolled factorization: on the CPU a LAPACK call
    costs more than the whole filter step for these small matrices."""
    n = S.shape[0]
    L = [[None] * n for _ in range(n)]
    ok = jnp.asarray(True)
    for j in range(n):
        d = S[j, j] - sum((L[j][k] ** 2 for k in range(j)), jnp.asarray(0.0))
        ok = ok & (d > 0)
        L[j][j] = jnp.sqrt(jnp.where(d > 0, d, 1.0))
        for i in range(j + 1, n):
            L[i][j] = (S[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), jnp.asarray(0.0))) / L[j][j]
    return ok
