"""How the data vary inside a sample interval: held (``interpolation="hold"``, the papers') or linear between the
interval's two samples (``"linear"``).

With held data the filter integrates a staircase: whatever the integrator, its error against the filter of the
continuous data is O(dt), so RKMK4 buys nothing over Lie-Euler (on Saccon's attitude example it is even worse).
With linear interpolation RKMK4's inner stages see current data: the error is O(dt^2) for smooth data (the
interpolation error) and O(dt^4), RKMK4's order, when the data are linear between samples.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef import simulate
from liemef.groups import SO3
from liemef.studies.experiments import attitude
from liemef.systems import System
from tolerances import SLOPE

DT = 0.01  # h = 10 ms
T_END, STEADY = 20.0, 10.0


@pytest.fixture(scope="module")
def attitude_errors():
    """Saccon et al. 2016, Sec. V-B at h = 10 ms: the experiment's system, initial state (60 deg off), alpha and
    K(0) (liemef.studies.experiments.attitude.setup), one filter step per sample. Noise-free data (the torque, and the
    directions of the paper's truth: geometric Euler with h = 1 ms), so that the filter's error after its
    transient is its integration error. Returns the attitude error rms (deg) over [10, 20] s per (integrator,
    interpolation)."""
    cfg = attitude.AttitudeConfig(dt=DT, duration=T_END)
    s = attitude.setup(cfg)
    ts = s.ts
    truth, _ = simulate(s.system, s.g0, attitude.paper_torque, ts, jax.random.key(0), substeps=10,
                        integrator=cfg.truth_integrator)
    us = np.asarray(jax.vmap(attitude.paper_torque)(jnp.asarray(ts)))
    ys = np.asarray(jax.vmap(s.system.output)(truth.g, jnp.asarray(ts)))
    out = {}
    for integrator, interpolation in (("rkmk4", "hold"), ("rkmk4", "linear"), ("lie-euler", "hold")):
        flt = liemef.MinimumEnergyFilter(s.system, curvature="exact", connection=cfg.connection,
                                         integrator=integrator, alpha=cfg.alpha, interpolation=interpolation,
                                         substeps=1)
        traj = flt.run(s.state0, ts, us, ys)
        assert traj.status.ok
        e_R = np.asarray(attitude.attitude_errors(truth.g, traj.g_hat))[:, 0]
        out[integrator, interpolation] = float(np.sqrt(np.mean(e_R[ts >= STEADY] ** 2)))
    print({f"{k[0]}/{k[1]}": f"{v:.4f} deg" for k, v in out.items()})
    return out


def test_rkmk4_needs_linear_interpolation(attitude_errors):
    """Measured rms over [10, 20] s: RKMK4 + hold 0.36 deg, Lie-Euler (hold; interpolation does not matter to
    it, it samples the data at the interval's start only) 0.18 deg, RKMK4 + linear 0.027 deg (part of which is
    the 1 ms Euler truth's own error)."""
    e = attitude_errors
    assert e["rkmk4", "hold"] > 1.3 * e["lie-euler", "hold"]  # held data: RKMK4 is worse
    assert e["rkmk4", "linear"] <= e["lie-euler", "hold"]  # linear: it is no worse ...
    assert e["rkmk4", "linear"] < 0.25 * e["lie-euler", "hold"]  # ... here several times better


# --- convergence slopes -------------------------------------------------------------------------------------------
def _angular_velocity(g, u, t):
    return u


def _direction(g, t):
    return g.as_matrix().T @ jnp.array([0.0, 0.0, 1.0])


T_SLOPE, DT0 = 1.0, 0.04
DTS = (DT0, DT0 / 2, DT0 / 4)
KNOTS = np.arange(0.0, T_SLOPE + 1e-9, DT0)


def smooth(t):
    u = np.stack([np.sin(3 * t), np.cos(2 * t), 0.5 * np.sin(5 * t + 1)], -1)
    y = np.stack([np.sin(t), 0.3 * np.cos(3 * t), np.cos(t)], -1)
    return u, y


_rng = np.random.default_rng(0)
_KU, _KY = smooth(KNOTS)
_KU, _KY = _KU + 0.5 * _rng.standard_normal(_KU.shape), _KY + 0.3 * _rng.standard_normal(_KY.shape)


def piecewise_linear(t):
    """Linear between the knots of the coarsest grid: every grid of DTS interpolates it exactly."""
    return (np.stack([np.interp(t, KNOTS, _KU[:, i]) for i in range(3)], -1),
            np.stack([np.interp(t, KNOTS, _KY[:, i]) for i in range(3)], -1))


@pytest.fixture(scope="module")
def so3_filter():
    """SO(3) with the angular velocity as input and one direction measured (density): a small nonabelian system.
    One compiled step serves both interpolations: with ``u_next``/``y_next`` left out the "linear" filter holds
    the samples, the same arithmetic as ``interpolation="hold"``."""
    sys_ = System(group_type=SO3, dynamics_fn=_angular_velocity, output_fn=_direction, B=0.3 * np.eye(3), D=np.eye(3),
                  Q=np.eye(3), R=np.eye(3), n_inputs=3)
    return liemef.MinimumEnergyFilter(sys_, curvature="exact", interpolation="linear", substeps=1)


def _final(flt, dt, signal, linear):
    ts = np.arange(int(round(T_SLOPE / dt)) + 1) * dt
    u, y = signal(ts)
    st = flt.init(SO3.exp(jnp.array([0.3, -0.2, 0.5])), np.eye(3))
    for k in range(ts.size - 1):
        st = flt.step(st, ts[k], u[k], y[k], dt, u_next=u[k + 1] if linear else None,
                      y_next=y[k + 1] if linear else None)
    return st


_REFERENCE = {}


@pytest.mark.parametrize(("signal", "interpolation", "slope"), [
    (smooth, "hold", 1.0), (smooth, "linear", 2.0), (piecewise_linear, "hold", 1.0), (piecewise_linear, "linear", 4.0),
])
def test_convergence_slope(so3_filter, signal, interpolation, slope):
    """Error of (g_hat, K) at t = 1 s against the same filter at 0.01/8 s with linear interpolation (the filter of the
    continuous data), halving dt from 0.04 s. Measured slopes: held data 1.00 (smooth or not); linear on smooth
    data 2.00 (the interpolation error, not RKMK4's order); linear on data linear between samples 3.9."""
    linear = interpolation == "linear"
    if signal not in _REFERENCE:
        _REFERENCE[signal] = _final(so3_filter, DTS[-1] / 8, signal, True)
    ref = _REFERENCE[signal]
    errs = []
    for dt in DTS:
        st = _final(so3_filter, dt, signal, linear)
        errs.append(max(np.abs(np.asarray(ref.g_hat.rminus(st.g_hat))).max(), np.abs(np.asarray(st.K - ref.K)).max()))
    slopes = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    print(signal.__name__, interpolation, [f"{e:.3g}" for e in errs], slopes)
    assert np.all(np.abs(slopes - slope) < SLOPE), slopes
