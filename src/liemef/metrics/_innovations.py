r"""The innovation monitor: whether a run's gain K is consistent with its own innovations, without a truth.

Before sample $k$ is used, the filter predicts it: the state at $t_k$ has seen the samples up to $k - 1$ (a sample
at ``ts[k]`` is used over ``[ts[k], ts[k+1])``), so against $\hat g_k$ and $K_k$ the innovation of each sensor

$$\nu_k = y_k \ominus h(\hat g_k), \qquad S_k = F K_k F^\top + J R_k J^\top, \qquad
\epsilon_k = \nu_k^\top S_k^{-1} \nu_k$$

is the prior one: $F$ the left-trivialized Jacobian of the output as the filter sees it, $R_k$ the sample's own
covariance (:func:`liemef.filters._base.sample_covariance`, the gates' own: a density sensor's information over
the interval, a sample sensor's per sample) and $J = \partial(y \ominus h)/\partial y$ (the identity for
$y - h$; for a direction on $S^2$ the projection onto the tangent plane, one degree of freedom less). When K
is the covariance of the left error, $\epsilon_k$ is $\chi^2$ with the sensor's degrees of freedom. The
monitor slides a window of the last $N$ present samples of each sensor along the run and flags the run where
the window's mean leaves its ``prob`` band $\chi^2_{dN}((1 \mp p)/2)/N$ for a sustained time.

What the innovations cannot see, a K wrong along a direction no sensor observes, the linearization leak bounds:
with $H_i$ the Hessian of output $i$ in the left coordinates at $\hat g_k$, $(N_k)_{ij} = \tfrac12
\operatorname{tr}(H_i K_k H_j K_k)$ is the covariance that the output's quadratic term adds to the innovation under
$\xi \sim N(0, K_k)$, and $\ell_k = \operatorname{tr}(S_k^{-1} N_k)$ is half a bound on the information that the
sample's linearization at $\hat g_k$ rather than at the truth can give any direction, relative to what $K_k$ holds
there. Summed over the same windows, a leak that stays at or above its limit makes a run "nonlinear". The rules,
the derivation and the rates measured are in the docs' page on the monitor (docs/innovations.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._times import time_said
from ._consistency import chi2_bounds

WINDOW_SECONDS, WINDOW_MIN, WINDOW_MAX = 5.0, 20, 500
"""The default window of a sensor: its present samples within 5 s, at least 20 and at most 500."""
SUSTAIN_WINDOWS = 1.5
"""The default sustain time of a sensor: this many of its windows' spans. One gross outlier keeps the windows that
hold it out of band for one span, a burst of them for the burst's length more: with 1.5, a burst shorter than half a
window is not enough, a fault that lasts is (for as long as half a window past its first window out). In a log too
short for that, the time from its first window to its last, where those two share no sample: no single sample can
put every window out, and a log whose every window is out says so. A log too short for two disjoint windows is not
judged at all: a single sample could put every window out, and no run of windows could last the sustain time."""
LEAK_LIMIT = 1.0
r"""The default limit of a window's linearization leak $\sum \ell_k$ over a sensor's window: at 1, the samples of one
window can, by their linearization at the estimate, give a direction they do not observe up to twice the information
K holds there (docs/innovations.md)."""
STATUSES = ("consistent", "inconsistent", "nonlinear", "not applicable")


def gain_is_covariance(flt) -> bool:
    """Whether the filter's K is meant as the covariance of its left error, so that innovations can test it:
    a system whose weights are noise levels in the sensors' units (a :class:`~liemef.systems.SensorSystem`;
    the papers' systems weigh with $Q = D^\\top D$ and K is then a gain, not a covariance), a filter that keeps a
    covariance (not the AHRS baselines, ``has_covariance = False``) and the theorem's E (not the printed
    ``constant_E="unit"``). The one place this is decided."""
    from ..systems import SensorSystem

    return (isinstance(getattr(flt, "system", None), SensorSystem) and getattr(flt, "has_covariance", True)
            and getattr(flt, "constant_E", "weighted") == "weighted")


# --- the normalized innovations, compiled once per filter structure ----------------------------------------------
def _nis_one(flt, g, K, t, dt, y, leak):
    r"""Per sensor block: the NIS of the sample ``y`` (NaN: a missing component) against the state ``(g, K)``,
    NaN where the block is not present or the state not finite; for a system with manifold residuals, instead,
    ``(present, nu, S, J)`` of the block, whose NIS and rank of $J$ (the sample's degrees of freedom)
    :func:`_manifold_nis` takes. With ``leak`` (static), each block's result is a pair: that and the sample's
    linearization leak $\operatorname{tr}(S^{-1} N)$ (module :func:`linearization_leak`; for manifold residuals
    the block's $N$, which :func:`_manifold_nis` projects)."""
    from ..filters import information_in_force, sample_covariance

    system = flt.system
    mask = jnp.isfinite(y)
    y0 = jnp.where(mask, y, 0.0)
    sample = jnp.asarray(flt.sample, dtype=bool)
    # the information in force and the sample's own noise as the filter's gates read them (filters._base)
    Wy = flt.adapted(information_in_force(flt.weights.Wy, sample, mask, dt, diagonal=flt.diagonal), y0)
    # forward over forward (not jax.hessian's reverse inside): an output linear in the coordinates gets a leak of
    # exactly 0
    seen = lambda xi: system.output_seen_from(y0, g.rplus(xi), t)  # noqa: E731
    zero = jnp.zeros(type(g).tangent_dim)
    h0, F = seen(zero), jax.jacfwd(seen)(zero)
    nu = y0 - h0
    Ks = 0.5 * (K + K.T)
    FKF = F @ Ks @ F.T
    if leak:
        HK = jnp.einsum("iab,bc->iac", jax.jacfwd(jax.jacfwd(seen))(zero), Ks)
        N = 0.5 * jnp.einsum("iab,jba->ij", HK, HK)  # the quadratic term's covariance under N(0, K)
    if system.manifold_residuals:
        h = system.output(g, t)
        J = jax.jacfwd(lambda yy: system.residual(yy, h, t))(y0)
    out = []
    for b in flt.blocks:
        sl = slice(b.start, b.stop)
        present = jnp.all(mask[sl])
        R = sample_covariance(Wy, dt, present, b)
        if system.manifold_residuals:
            # S is singular where J is (a direction's normal component): its pseudo-inverse on J's range, taken
            # by NumPy after the program (_manifold_nis): a batched SVD or eigh inside this vmapped XLA program
            # stalled XLA CPU's Eigen pool now and then (every worker idle)
            Jb = J[sl, sl]
            one = (present, nu[sl], FKF[sl, sl] + Jb @ R @ Jb.T, Jb)
            out.append((one, N[sl, sl]) if leak else one)
        else:
            S = FKF[sl, sl] + R
            q = nu[sl] @ jnp.linalg.solve(S, nu[sl])
            one = jnp.where(present & jnp.isfinite(q), q, jnp.nan)
            if leak:
                ell = jnp.trace(jnp.linalg.solve(S, N[sl, sl]))
                one = (one, jnp.where(present & jnp.isfinite(ell), ell, jnp.nan))
            out.append(one)
    return out


def _manifold_nis(present, nu, S, J, N=None):
    r"""The NIS of a manifold-residual block over all samples, by NumPy: ``nu`` (M, d) against the
    pseudo-inverse of ``S`` (M, d, d) on the range of ``J`` (M, d, d), and the rank of ``J`` (the sample's
    degrees of freedom); NaN where the block is not present or the result not finite. With ``N`` (M, d, d), the
    quadratic term's covariance in the residual's space, also the leak $\operatorname{tr}(S^+ P N P)$ with $P$
    the orthogonal projector onto the range of $J$: the part of the curvature that moves the residual (not the
    part normal to a direction's sphere)."""
    present, nu, S, J = (np.asarray(a) for a in (present, nu, S, J))
    finite = np.isfinite(S).all(axis=(1, 2)) & np.isfinite(J).all(axis=(1, 2)) & np.isfinite(nu).all(axis=1)
    S, J, nu = (np.where(finite.reshape((-1,) + (1,) * (a.ndim - 1)), a, 0.0) for a in (S, J, nu))
    U, s, _ = np.linalg.svd(J)
    kept = s > 1e-6 * s.max(axis=1, keepdims=True)
    rank = np.sum(kept, axis=1)
    Sp = np.linalg.pinv(S, rcond=1e-9, hermitian=True)
    q = np.einsum("ni,nij,nj->n", nu, Sp, nu)
    q = np.where(present & finite & np.isfinite(q), q, np.nan)
    if N is None:
        return q, rank
    N = np.asarray(N)
    ok = finite & np.isfinite(N).all(axis=(1, 2))
    P = np.einsum("nik,nk,njk->nij", U, kept.astype(float), U)
    ell = np.einsum("nij,njk,nkl,nli->n", Sp, P, np.where(ok[:, None, None], N, 0.0), P)
    return q, rank, np.where(present & ok & np.isfinite(ell), ell, np.nan)


@eqx.filter_jit
def _nis_all(flt, g, K, ts, dts, ys, leak=False):
    # a loop over the samples (lax.map), not a vmap: the vmapped program's large batched contractions stalled
    # XLA CPU's multi-threaded Eigen pool now and then (every worker idle, the caller waiting for ever), in the
    # test suite and on a 17 143-sample log; the loop's small per-sample products stay on one thread
    return jax.lax.map(lambda a: _nis_one(flt, *a, leak), (g, K, ts, dts, ys))


def _samples_of(traj, ts, name="traj"):
    """The indices into ``ts`` of the trajectory's states (every one, or every M-th with ``keep_every``)."""
    tt = np.asarray(traj.ts, dtype=np.float64)
    idx = np.searchsorted(ts, tt)
    if tt.ndim != 1 or idx.max(initial=0) >= ts.size or not np.array_equal(ts[np.minimum(idx, ts.size - 1)], tt):
        raise ValueError(f"{name}: expected a run over the log ts (its times a subset of ts, as with keep_every), "
                         f"got {tt.size} times from {tt[:1]} that are not among the log's")
    return idx


def innovation_nis(flt, traj, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike):
    r"""The normalized innovation squared of every sample of every sensor of a run (module docstring):
    ``(nis, dof)`` with ``nis`` (N, number of sensors) over the log's samples (NaN where the sensor has no
    sample, the state is NaN after a failure, the run kept no state there (``keep_every``) or the sample is the
    log's last, which no interval uses) and ``dof`` the sensors' degrees of freedom. ``flt`` the filter that made
    ``traj`` from the log ``ts``, ``us``, ``ys`` (checked as :meth:`~liemef.filters.AbstractFilter.run` checks
    them). NumPy arrays."""
    nis, dof, _ = _per_sample(flt, traj, ts, us, ys, leak=False)
    return nis, dof


def linearization_leak(flt, traj, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike) -> np.ndarray:
    r"""The linearization leak $\ell_k = \operatorname{tr}(S_k^{-1} N_k)$ of every sample of every sensor of a run
    (module docstring): (N, number of sensors), NaN where :func:`innovation_nis` has no NIS. $N_k$, with
    $(N_k)_{ij} = \tfrac12 \operatorname{tr}(H_i K_k H_j K_k)$ and $H_i$ the Hessian of output $i$ in the left
    coordinates at $\hat g_k$, is the covariance of the output's quadratic term under $\xi \sim N(0, K_k)$; $2\ell_k$
    bounds the information that the sample's linearization at $\hat g_k$ rather than at the truth can give a
    direction it does not observe, relative to what $K_k$ holds there (docs/innovations.md derives it). For a
    sensor with its own residual, only the part of $N$ in the range of $J = \partial(y \ominus h)/\partial y$
    counts. Same arguments and checks as :func:`innovation_nis`."""
    return _per_sample(flt, traj, ts, us, ys, leak=True)[2]


def _per_sample(flt, traj, ts, us, ys, leak):
    """``(nis, dof, leak)`` of :func:`innovation_nis` and :func:`linearization_leak` from one compiled loop (the
    leak None unless asked for)."""
    from ..filters import check_log

    ts, us, ys, _ = check_log(flt, ts, us, ys, (), math.inf)
    idx = _samples_of(traj, ts)
    K = np.asarray(traj.K, dtype=np.float64)
    n = flt.system.group.tangent_dim
    if K.shape != (idx.size, n, n):
        raise ValueError(f"traj: expected K of shape ({idx.size}, {n}, {n}) beside its {idx.size} times, got "
                         f"{K.shape}")
    use = idx < ts.size - 1  # the last sample is used over no interval
    idx = idx[use]
    g = jax.tree_util.tree_map(lambda a: np.asarray(a)[use], traj.g_hat)
    dts = ts[idx + 1] - ts[idx]
    # padded to a power of two (at least 64) with copies of the first sample, missing: one compilation serves
    # every log of a length bucket
    M = idx.size
    pad = max(64, 1 << max(0, (M - 1).bit_length())) - M

    def padded(a, fill=None):
        a = np.asarray(a)
        extra = np.repeat(a[:1], pad, axis=0) if fill is None else np.full((pad,) + a.shape[1:], fill)
        return np.concatenate([a, extra]) if M else np.zeros((0,) + a.shape[1:])

    nis = np.full((ts.size, len(flt.blocks)), np.nan)
    ell = nis.copy() if leak else None
    if M == 0:
        return nis, tuple(b.dim for b in flt.blocks), ell
    blocks = _nis_all(flt, jax.tree_util.tree_map(padded, g), padded(K[use]), padded(ts[idx]), padded(dts),
                      padded(ys[idx], np.nan), leak)
    q, rank, e = np.empty((M, len(blocks))), np.empty((M, len(blocks)), dtype=int), np.empty((M, len(blocks)))
    for i, (b, out) in enumerate(zip(flt.blocks, blocks, strict=True)):
        if leak:
            out, extra = out  # the leak, or a manifold residual's N
        if isinstance(out, tuple):
            parts = _manifold_nis(*(np.asarray(a)[:M] for a in out), *((np.asarray(extra)[:M],) if leak else ()))
            q[:, i], rank[:, i] = parts[:2]
            if leak:
                e[:, i] = parts[2]
        else:
            q[:, i], rank[:, i] = np.asarray(out)[:M], b.dim
            if leak:
                e[:, i] = np.asarray(extra)[:M]
    nis[idx] = q
    if leak:
        ell[idx] = e
    seen = np.isfinite(q)
    dof = tuple(int(rank[seen[:, i], i].max()) if seen[:, i].any() else b.dim for i, b in enumerate(flt.blocks))
    return nis, dof, ell


# --- the verdict -------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorVerdict:
    """One sensor's windows: its ``dof``, ``window`` (samples) spanning ``span`` s, the ``band`` of a window's
    mean NIS, the present ``samples`` and full ``windows``, the fraction of windows out of band, the time of the
    first one out (``first_out``), the longest excursion (``longest``: start and end time of a run of windows out
    of band on one ``side``, "high" or "low") and whether it lasted ``sustain`` s (``sustained``)."""

    name: str
    dof: int
    samples: int
    window: int | None = None
    span: float | None = None
    band: tuple[float, float] | None = None
    windows: int = 0
    fraction_out: float | None = None
    first_out: float | None = None
    longest: tuple[float, float, str] | None = None
    sustain: float | None = None
    mean_nis: float | None = None
    extent: float | None = None
    """The time from the first full window to the last (s): an excursion can last at most this long (None: not
    known, and the sensor is judged)."""
    leak_limit: float | None = None
    """The limit of a window's leak (None: the leak was not computed)."""
    leak_peak: float | None = None
    r"""The largest window's leak $\sum \ell_k$."""
    leak_median: float | None = None
    """The median window's leak, each sample's counted up to the limit: the run's typical one, which an early
    transient from a large K0 does not move."""
    leak_longest: tuple[float, float] | None = None
    """Start and end time of the longest run of windows whose leak reached ``leak_limit``."""

    @property
    def sustained(self) -> bool:
        """Whether the longest excursion lasted at least the sustain time."""
        return self.longest is not None and self.longest[1] - self.longest[0] >= self.sustain

    @property
    def judged(self) -> bool:
        """Whether an excursion could have lasted the sustain time: the full windows span at least that long. A
        sensor whose windows span less (its log too short for two disjoint windows, with the default sustain) is
        not judged, neither consistent nor inconsistent."""
        return self.windows > 0 and (self.extent is None or self.extent >= self.sustain)

    @property
    def nonlinear(self) -> bool:
        """Whether the windows' leak stayed at or above its limit for at least the sustain time."""
        return self.leak_longest is not None and self.leak_longest[1] - self.leak_longest[0] >= self.sustain

    def as_dict(self) -> dict:
        """JSON-ready."""
        return {"name": self.name, "dof": self.dof, "samples": self.samples, "window": self.window,
                "window_s": self.span, "band": None if self.band is None else list(self.band),
                "windows": self.windows, "fraction_out": self.fraction_out, "first_out_t": self.first_out,
                "mean_nis": self.mean_nis,
                "longest_excursion": None if self.longest is None else {
                    "start": self.longest[0], "end": self.longest[1], "side": self.longest[2],
                    "sustained": self.sustained},
                "sustain_s": self.sustain, "windows_extent_s": self.extent, "judged": self.judged,
                "inconsistent": self.sustained,
                "leak": None if self.leak_limit is None else {
                    "limit": self.leak_limit, "peak": self.leak_peak, "median": self.leak_median,
                    "longest": None if self.leak_longest is None else {
                        "start": self.leak_longest[0], "end": self.leak_longest[1]},
                    "nonlinear": self.nonlinear}}


@dataclass(frozen=True)
class InnovationReport:
    """What :func:`innovation_monitor` found: ``status`` (one of :data:`STATUSES`), per sensor a
    :class:`SensorVerdict`, the rules applied (``window``, ``prob``, ``sustain`` as given, None: the defaults;
    ``leak``, the leak's limit) and, for "not applicable", the ``reason``."""

    status: str
    sensors: tuple[SensorVerdict, ...] = ()
    window: int | None = None
    prob: float = 0.999
    sustain: float | None = None
    leak: float = LEAK_LIMIT
    reason: str = ""
    nis: np.ndarray | None = field(default=None, repr=False)
    """(N, sensors): every sample's NIS (NaN where none)."""
    leaks: np.ndarray | None = field(default=None, repr=False)
    """(N, sensors): every sample's linearization leak (NaN where none)."""
    t0: float = 0.0
    """The log's first time: the message says its times relative to it (``t = t0 + 12.3 s``)."""

    def as_dict(self) -> dict:
        """JSON-ready: the status, the reason, the rules and each sensor's :meth:`SensorVerdict.as_dict`."""
        return {"status": self.status, "reason": self.reason or None,
                "definition": "per sensor, the mean over a sliding window of its last `window` present samples of "
                              "the normalized innovation squared nu^T S^-1 nu (nu = y (-) h(g_hat) before the "
                              "sample's update, S = F K F^T + J R J^T); inconsistent where it stays outside its "
                              "chi-square `prob` band for `sustain_s` seconds; nonlinear (where not inconsistent) "
                              "where the sum over the same windows of the linearization leak tr(S^-1 N) (N the "
                              "covariance of the output's quadratic term under N(0, K)) stays at or above `leak` "
                              "for `sustain_s` seconds",
                "window": self.window, "prob": self.prob, "sustain": self.sustain,
                "leak": self.leak if math.isfinite(self.leak) else None,
                "sensors": [s.as_dict() for s in self.sensors]}

    def message(self) -> str:
        """One line: the status and, where inconsistent or nonlinear, which sensor, when and on which side."""
        if self.status == "not applicable":
            return f"Innovation monitor: not applicable ({self.reason})"
        judged = [s for s in self.sensors if s.judged]
        if self.status == "consistent":
            return ("Innovation monitor: consistent (" + "; ".join(
                [f"{s.name}: {100 * (1 - s.fraction_out):.1f} % of {s.windows} windows of {s.window} samples in "
                 f"the {100 * self.prob:g} % band [{s.band[0]:.3g}, {s.band[1]:.3g}]" for s in judged]
                + [f"{s.name}: not judged, its windows span {s.extent:.3g} s of the {s.sustain:.3g} s an excursion "
                   f"must last" for s in self.sensors if s.windows and not s.judged]) + ")")
        said = []
        for s in (s for s in judged if s.sustained):
            start, end, side = s.longest
            said.append(f"{s.name}: mean NIS of {s.window} samples {'above' if side == 'high' else 'below'} its "
                        f"{100 * self.prob:g} % band [{s.band[0]:.3g}, {s.band[1]:.3g}] from "
                        f"{time_said(start, self.t0)} to {time_said(end, self.t0)} (first out at "
                        f"{time_said(s.first_out, self.t0)}; the run's mean NIS {s.mean_nis:.3g} for {s.dof} dof): "
                        f"K {'understates' if side == 'high' else 'overstates'} the errors")
        curved = []
        for s in (s for s in judged if s.nonlinear):
            start, end = s.leak_longest
            curved.append(f"{s.name}: the linearization leak of {s.window} samples reached {s.leak_limit:g} from "
                          f"{time_said(start, self.t0)} to {time_said(end, self.t0)} (peak {s.leak_peak:.3g}): "
                          "over K's spread the output's curvature can feed directions this sensor does not "
                          "observe with information no sample holds, and K may understate the errors there, where "
                          "the innovations cannot show it")
        if self.status == "inconsistent":
            return "Innovation monitor: INCONSISTENT: " + "; ".join(said + [f"also nonlinear: {c}" for c in curved])
        return "Innovation monitor: NONLINEAR: " + "; ".join(curved)


def _excursions(out, side):
    """The runs of consecutive True in ``out`` with one ``side`` each: (start, end) indices."""
    runs, start = [], None
    for j in range(out.size + 1):
        here = j < out.size and out[j]
        if start is not None and (not here or side[j] != side[start]):
            runs.append((start, j - 1))
            start = None
        if here and start is None:
            start = j
    return runs


def _longest(out, side, tw) -> tuple[int, int] | None:
    """The (start, end) indices of the longest excursion of ``out`` (:func:`_excursions`) in the windows' times
    ``tw``; None without any."""
    runs = _excursions(out, side)
    return max(runs, key=lambda r: tw[r[1]] - tw[r[0]]) if runs else None


def _window_sums(x, N: int):
    """The sums of ``x`` over every window of ``N`` consecutive samples."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    return c[N:] - c[:-N]


def _verdict(name, dof, ts, q, window, prob, sustain, ell=None, limit=LEAK_LIMIT) -> SensorVerdict:
    """One sensor's windows over its present samples ``q`` at times ``ts``, and over their leaks ``ell`` (None:
    not computed) with the window's limit ``limit``."""
    ok = np.isfinite(q)
    t, q = ts[ok], q[ok]
    if t.size < 2:
        return SensorVerdict(name, dof, int(t.size))
    rate = (t.size - 1) / (t[-1] - t[0])
    N = window if window is not None else int(np.clip(round(WINDOW_SECONDS * rate), WINDOW_MIN, WINDOW_MAX))
    if t.size < N:
        return SensorVerdict(name, dof, int(t.size), window=N)
    span = N / rate
    lo, hi = chi2_bounds(dof, N, prob)
    mean = _window_sums(q, N) / N
    tw = t[N - 1:]  # a window's time: its last sample's
    hold = SUSTAIN_WINDOWS * span if sustain is None else sustain
    if sustain is None and t.size >= 2 * N:  # a short log (SUSTAIN_WINDOWS): its first and last windows are disjoint
        hold = min(hold, float(tw[-1] - tw[0]))
    out = (mean < lo) | (mean > hi)
    side = np.where(mean > hi, 1, -1)
    first = float(tw[np.argmax(out)]) if out.any() else None
    run = _longest(out, side, tw)
    longest = None if run is None else (float(tw[run[0]]), float(tw[run[1]]), "high" if side[run[0]] > 0 else "low")
    leaks = {}
    if ell is not None:
        # a leak that cannot be computed where the NIS can (a Hessian that is not finite) counts as the limit.
        # Each sample's leak enters the windows' verdicts and median clipped at the limit: that changes no verdict
        # (one such sample puts its window at the limit), and the cumulative sum of the windows after a huge early
        # leak (K0 far larger than the errors) stays exact. The peak is of the leaks as they are.
        e = np.asarray(ell, dtype=np.float64)[ok]
        e = np.where(np.isfinite(e), e, limit)
        total = _window_sums(np.minimum(e, limit), N)
        run = _longest(total >= limit, np.ones(total.size), tw)
        leaks = {"leak_limit": float(limit), "leak_peak": float(np.max(_window_sums(e, N))),
                 "leak_median": float(np.median(total)),
                 "leak_longest": None if run is None else (float(tw[run[0]]), float(tw[run[1]]))}
    return SensorVerdict(name, dof, int(t.size), window=N, span=float(span), band=(lo, hi), windows=int(mean.size),
                         fraction_out=float(out.mean()), first_out=first, longest=longest, sustain=float(hold),
                         mean_nis=float(q.mean()), extent=float(tw[-1] - tw[0]), **leaks)


def innovation_monitor(flt, traj, ts: ArrayLike, us: ArrayLike | None, ys: ArrayLike, *, window: int | None = None,
                       prob: float = 0.999, sustain: float | None = None,
                       leak: float = LEAK_LIMIT) -> InnovationReport:
    r"""Whether the run ``traj`` of the filter ``flt`` over the log ``ts``, ``us``, ``ys`` is consistent with its
    own innovations (module docstring), without a truth.

    Per sensor, the mean NIS over a sliding window of its last ``window`` present samples (default: the samples
    within 5 s, at least 20 and at most 500) is compared with its two-sided ``prob`` band
    $(\chi^2_{dN}((1-p)/2), \chi^2_{dN}((1+p)/2))/N$ (:func:`chi2_bounds`, $d$ the sensor's degrees of
    freedom). A run of windows out of band on one side that lasts at least ``sustain`` seconds (default: 1.5
    windows' spans, per sensor, or in a shorter log the time from its first window to its last where those share
    no sample, :data:`SUSTAIN_WINDOWS`) makes the status "inconsistent". Otherwise, where the sum of the
    linearization leak (:func:`linearization_leak`) over the same windows stays at or above ``leak`` for the
    sustain time on some sensor, the status is "nonlinear": the innovations do not contradict K, but the
    output's curvature over K's spread can make K understate the errors along directions that sensor does not
    observe, which no innovation shows (``leak=math.inf`` turns this off). Else "consistent". A sensor whose full
    windows span less than its sustain time (a log with fewer than two disjoint windows of it, at the default
    sustain) is not judged: no excursion could last long enough. "not applicable" where K is not a covariance
    (:func:`gain_is_covariance`), no sensor has a full window, or none is judged (the reason says so). States
    that are NaN after a failure are skipped (the run's status speaks for them), and so are the sensors whose output
    does not depend on the state (:attr:`~liemef.systems.Sensor.covariate`: another sensor's covariates, no
    innovation).
    Works on a run of either engine, with ``keep_every`` (only the samples with a state kept are judged), for
    every filter of the library. ValueError naming the argument for bad input."""
    if window is not None and not (isinstance(window, int | np.integer) and not isinstance(window, bool)
                                   and window >= 1):
        raise ValueError(f"window: expected a number of samples >= 1 (or None: the default rule), got {window!r}")
    if isinstance(prob, bool) or not (isinstance(prob, int | float | np.floating) and 0.0 < prob < 1.0):
        raise ValueError(f"prob: expected a probability in (0, 1), got {prob!r}")
    if sustain is not None and (isinstance(sustain, bool) or not isinstance(sustain, int | float | np.number)
                                or not (math.isfinite(sustain) and sustain >= 0)):
        raise ValueError(f"sustain: expected a finite time >= 0 in seconds (or None: 1.5 windows' spans), "
                         f"got {sustain!r}")
    if isinstance(leak, bool) or not (isinstance(leak, int | float | np.number) and leak > 0):
        raise ValueError(f"leak: expected a window's linearization leak > 0 (math.inf: no limit), got {leak!r}")
    for name, v in (("flt", flt), ("traj", traj)):
        if not all(hasattr(v, a) for a in (("system",) if name == "flt" else ("ts", "g_hat", "K"))):
            raise ValueError(f"{name}: expected a liemef {'filter' if name == 'flt' else 'Trajectory'}, got "
                             f"{type(v).__name__}")
    rules = {"window": None if window is None else int(window), "prob": float(prob),
             "sustain": None if sustain is None else float(sustain), "leak": float(leak)}
    if not gain_is_covariance(flt):
        return InnovationReport("not applicable", reason="K is not a covariance: the system's weights are not noise "
                                "levels in the sensors' units, or the filter keeps no covariance", **rules)
    measured = math.isfinite(leak)
    nis, dof, ell = _per_sample(flt, traj, ts, us, ys, leak=measured)
    # a covariate (an output that does not depend on the state) carries no innovation: not judged
    covariates = {s.name for s in getattr(flt.system, "sensors", ()) if s.covariate}
    for i, b in enumerate(flt.blocks):
        if b.name in covariates:
            nis[:, i] = np.nan
            if measured:
                ell[:, i] = np.nan
    t = np.asarray(ts, dtype=np.float64)
    sensors = tuple(_verdict(b.name, d, t, nis[:, i], rules["window"], rules["prob"], rules["sustain"],
                             ell[:, i] if measured else None, leak)
                    for i, (b, d) in enumerate(zip(flt.blocks, dof, strict=True)))
    if not any(s.windows for s in sensors):
        return InnovationReport("not applicable", sensors, reason="no sensor has a full window of samples "
                                f"({', '.join(f'{s.name} {s.samples}' for s in sensors)} present)", nis=nis,
                                leaks=ell, t0=float(t[0]), **rules)
    if not any(s.judged for s in sensors):
        return InnovationReport("not applicable", sensors, reason="the log is too short to judge: no sensor's full "
                                "windows span its sustain time (" + ", ".join(
                                    f"{s.name}: {s.extent:.3g} s of {s.sustain:.3g} s" for s in sensors if s.windows)
                                + ")", nis=nis, leaks=ell, t0=float(t[0]), **rules)
    status = ("inconsistent" if any(s.sustained for s in sensors) else
              "nonlinear" if any(s.nonlinear for s in sensors) else "consistent")
    return InnovationReport(status, sensors, nis=nis, leaks=ell, t0=float(t[0]), **rules)
