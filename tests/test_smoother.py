"""The minimum-energy smoother (liemef.smoothers): the Rauch-Tung-Striebel smoother on a linear system,
independent least-squares solves on SE(2) and on SE_2(3), the marginal covariances against the inverse of the
whole Hessian, robust losses, consistency by Monte Carlo, and failures as values."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize, stats

import liemef
from liemef.groups import SE2, Rn
from liemef.smoothers import _batch
from liemef.studies.experiments import inertial as ins
from liemef.studies.experiments import localization as loc
from liemef.systems import Noise, Sensor, SensorSystem, System, planar_localization

A = np.array([[0.0, 1.0], [-0.5, -0.2]])
G = np.array([[0.0], [1.0]])
Q_DENSITY = np.array([0.3, 0.5])
SIGMA = 0.4
DT = 0.05
RTS = 1e-10
"""The smoother on a linear system against the Rauch-Tung-Striebel recursion: one exact Gauss-Newton step, the
floor (1e-6 std) far below the noise."""
LSQ = 1e-8
"""The smoother against scipy's least squares on the same cost, both converged to their tolerances."""


def _linear(g, u, t):
    return jnp.asarray(A) @ g.x + jnp.asarray(G) @ u


def _position(g, t):
    return g.x[:1]


def _linear_log(meaning: str, seed: int = 2, N: int = 41):
    noise = Noise.sample(SIGMA) if meaning == "sample" else Noise.density(SIGMA)
    system = SensorSystem(Rn[2], _linear, (Sensor("pos", _position, noise),), Noise.density(Q_DENSITY),
                          inputs=("a",))
    rng = np.random.default_rng(seed)
    ts = np.arange(N) * DT
    us = rng.standard_normal((N, 1))
    ys = np.full((N, 1), np.nan)
    ys[::3, 0] = rng.standard_normal(ys[::3].shape[0])
    ys[-1, 0] = 0.3  # a sample at the last time: it measures the last state (a density one has no interval)
    return system, ts, us, ys


def _rts(ts, us, ys, x0, P0, R, Qd):
    """The textbook Kalman filter (update with y_k at t_k, predict with u_k) and Rauch-Tung-Striebel pass on
    x_{k+1} = F x_k + B u_k + w_k (Euler's discretization), written out here."""
    F, B, H = np.eye(2) + A * DT, G * DT, np.array([[1.0, 0.0]])
    N = ts.size
    xf, Pf, xp, Pp = np.zeros((N, 2)), np.zeros((N, 2, 2)), np.zeros((N, 2)), np.zeros((N, 2, 2))
    x, P = x0.copy(), P0.copy()
    for k in range(N):
        xp[k], Pp[k] = x, P
        if np.isfinite(ys[k, 0]) and R[k] is not None:
            S = H @ P @ H.T + R[k]
            Kg = P @ H.T @ np.linalg.inv(S)
            x = x + Kg @ (ys[k] - H @ x)
            P = (np.eye(2) - Kg @ H) @ P
        xf[k], Pf[k] = x, P
        x, P = F @ x + B @ us[k], F @ P @ F.T + Qd
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(N - 2, -1, -1):
        C = Pf[k] @ F.T @ np.linalg.inv(Pp[k + 1])
        xs[k] = xf[k] + C @ (xs[k + 1] - xp[k + 1])
        Ps[k] = Pf[k] + C @ (Ps[k + 1] - Pp[k + 1]) @ C.T
    return xs, Ps


@pytest.mark.parametrize("meaning", ["sample", "density"])
def test_linear_system_smoother_is_rauch_tung_striebel(meaning):
    """On x_{k+1} = x_k + (A x_k + G u_k) dt + w_k, w_k ~ N(0, diag(q^2) dt), with a sample sensor (each sample
    once, the last one included) or a density one (std s: variance s^2/dt per interval, none at the last time),
    and missing samples, the smoother's states and marginal covariances are the RTS smoother's to 1e-10."""
    system, ts, us, ys = _linear_log(meaning)
    x0, P0 = np.array([0.5, -0.3]), np.diag([1.0, 2.0])
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    sm = liemef.smooth(flt, flt.init(Rn[2](x0), K0=P0), ts, us, ys)
    assert sm.ok and sm.status == "converged", sm.message
    N = ts.size
    R = [np.array([[SIGMA**2]]) if meaning == "sample" else
         (np.array([[SIGMA**2 / DT]]) if k < N - 1 else None) for k in range(N)]
    xs, Ps = _rts(ts, us, ys, x0, P0, R, np.diag(Q_DENSITY**2) * DT)
    np.testing.assert_allclose(np.asarray(sm.g.x), xs, atol=RTS)
    np.testing.assert_allclose(np.asarray(sm.P), Ps, atol=RTS)
    assert float(sm.cost) <= float(sm.cost_init)


def test_the_test_rts_is_filterpys_without_input():
    """The RTS recursion written in this file is filterpy's ``rts_smoother`` where the input is zero (filterpy's
    takes none)."""
    from filterpy.kalman import KalmanFilter

    system, ts, _, ys = _linear_log("sample")
    us = np.zeros((ts.size, 1))
    x0, P0, Qd = np.array([0.5, -0.3]), np.diag([1.0, 2.0]), np.diag(Q_DENSITY**2) * DT
    xs, Ps = _rts(ts, us, ys, x0, P0, [np.array([[SIGMA**2]])] * ts.size, Qd)
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x, kf.P, kf.H, kf.R, kf.F, kf.Q = x0.copy(), P0.copy(), np.array([[1.0, 0.0]]), np.array([[SIGMA**2]]), \
        np.eye(2) + A * DT, Qd
    Xs, Pfs = [], []
    for k in range(ts.size):
        if np.isfinite(ys[k, 0]):
            kf.update(ys[k])
        Xs.append(kf.x.copy())
        Pfs.append(kf.P.copy())
        kf.predict()
    ref_x, ref_P, _, _ = kf.rts_smoother(np.array(Xs), np.array(Pfs))
    np.testing.assert_allclose(xs, ref_x, atol=1e-12)
    np.testing.assert_allclose(Ps, ref_P, atol=1e-12)


# --- SE(2): an independent solve and the covariances ----------------------------------------------------------
@pytest.fixture(scope="module")
def localization():
    """2 s of the ukfm localization at 100 Hz with a fix every 0.25 s and a 10 deg initial heading error, with
    odometry 10-30x noisier than ukfm's and 0.5 m fixes, so that the problem is well conditioned (ukfm's stiff
    odometry gives a Hessian of condition 1e10, where two solvers can only agree to about 1e-7)."""
    c = loc.LocalizationConfig(duration=2.0, gps_period=0.25, steady=0.0, theta0_std=np.deg2rad(10.0),
                               odometry_std=(0.2, 0.3, 0.3), gps_std=0.5)
    vstd, lstd, wstd = c.odometry_std
    system = planar_localization(odometry_std=(wstd, vstd, lstd), odometry_rate=1.0 / c.dt, gps_std=c.gps_std)
    flt = liemef.MinimumEnergyFilter(system)
    # the truth moves by the model's own step with the true input (the scenario's polygon would be a model
    # error of 2.5 mm per step against an odometry noise of 0.1 mm)
    ts = jnp.asarray(c.ts)
    true_us = jnp.tile(jnp.asarray(loc.true_input(c)), (ts.size, 1))
    truth = _batch.dead_reckoning(system, flt.integrator, SE2.identity(), ts, true_us)
    K0 = np.diag([c.theta0_std**2, 1e-4, 1e-4])
    return c, truth, system, flt, K0


def _localization_run(localization, key, **options):
    """One run: the scenario's log, and an initial estimate whose error is drawn from the prior N(0, K0)."""
    c, truth, _, flt, K0 = localization
    k_log, k_0 = jax.random.split(key)
    log, _ = loc.sensor_log(c, truth, loc.jax_draws(c, k_log))
    xi = jnp.sqrt(jnp.diag(jnp.asarray(K0))) * jax.random.normal(k_0, (3,))
    g0 = truth[0] @ SE2.exp(-xi)  # the truth is g0 exp(xi): the left error xi ~ N(0, K0)
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    return ts, us, ys, g0, liemef.smooth(flt, flt.init(g0, K0=K0), ts, us, ys, **options)


def _se2_matrices(c):
    """SE(2) matrices (..., 3, 3) from coordinates (..., 3) = (theta, x, y)."""
    th, x, y = c[..., 0], c[..., 1], c[..., 2]
    cs, sn, o, i = jnp.cos(th), jnp.sin(th), jnp.zeros_like(th), jnp.ones_like(th)
    return jnp.stack([jnp.stack([cs, -sn, x], -1), jnp.stack([sn, cs, y], -1), jnp.stack([o, o, i], -1)], -2)


def _v_terms(th):
    small = jnp.abs(th) < 1e-6
    t = jnp.where(small, 1.0, th)
    return jnp.where(small, 1.0 - th**2 / 6.0, jnp.sin(t) / t), jnp.where(small, th / 2.0, (1.0 - jnp.cos(t)) / t)


def _se2_log(M):
    """SE(2)'s log (..., 3) in liemef's order (omega, v_x, v_y): theta, then V(theta)^-1 p."""
    th = jnp.arctan2(M[..., 1, 0], M[..., 0, 0])
    a, b = _v_terms(th)
    px, py = M[..., 0, 2], M[..., 1, 2]
    det = a * a + b * b
    return jnp.stack([th, (a * px + b * py) / det, (-b * px + a * py) / det], -1)


def _se2_exp(xi):
    th, vx, vy = xi[..., 0], xi[..., 1], xi[..., 2]
    a, b = _v_terms(th)
    return _se2_matrices(jnp.stack([th, a * vx - b * vy, b * vx + a * vy], -1))


def test_localization_smoother_is_scipy_least_squares_on_the_group(localization):
    """The same cost written again without liemef's groups (SE(2) by its 3 x 3 matrices and a closed-form log,
    the odometry step g exp(u dt), fixes on the position), each pose by its coordinates (theta, x, y), minimized
    by scipy's least squares (its Jacobian by autodiff of those formulas) from a start off the smoother's
    minimizer: the same minimizer to 1e-8."""
    c, truth, system, flt, K0 = localization
    ts, us, ys, g0, sm = _localization_run(localization, jax.random.key(5), integrator="lie-euler", tol=1e-12)
    assert sm.ok, sm.message
    N = ts.size
    dt = c.dt
    B, R = np.asarray(system.B), np.asarray(system.R)
    Qd = B @ np.linalg.solve(R, B.T) * dt
    Lq = np.linalg.cholesky(np.linalg.inv(Qd)).T
    L0 = np.linalg.cholesky(np.linalg.inv(K0)).T
    Wy = np.asarray(system.information())
    Lm = np.linalg.cholesky(Wy).T
    G0 = np.asarray(g0.as_matrix())
    lam = np.stack([np.asarray(system.dynamics(SE2.identity(), jnp.asarray(u), 0.0)) for u in us[:-1]])
    fixes = np.flatnonzero(np.isfinite(ys[:, 0]))

    E = _se2_exp(jnp.asarray(lam * dt))

    @jax.jit
    def residuals(z):
        X = _se2_matrices(z.reshape(N, 3))
        r0 = L0 @ _se2_log(jnp.linalg.solve(G0, X[0]))
        rp = _se2_log(jnp.linalg.solve(X[:-1] @ E, X[1:])) @ Lq.T
        rm = (X[fixes, :2, 2] - ys[fixes]) @ Lm.T
        return jnp.concatenate([r0, rp.ravel(), rm.ravel()])

    jacobian = jax.jit(jax.jacfwd(residuals))
    z0 = np.asarray(sm.g.coords()).ravel() + 1e-3  # off the smoother's minimizer
    res = optimize.least_squares(lambda z: np.asarray(residuals(z)), z0, jac=lambda z: np.asarray(jacobian(z)),
                                 method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    # scipy's LM stops where its own tests say, up to 1e-8 off along the flattest direction (the Jacobian's
    # condition number is about 2500): three Gauss-Newton steps by numpy's lstsq finish its minimization
    z = res.x
    for _ in range(3):
        z = z - np.linalg.lstsq(np.asarray(jacobian(z)), np.asarray(residuals(z)), rcond=None)[0]
    print(f"smoother against least squares: {np.max(np.abs(z.reshape(N, 3) - np.asarray(sm.g.coords()))):.2e}")
    np.testing.assert_allclose(z.reshape(N, 3), np.asarray(sm.g.coords()), atol=LSQ)
    np.testing.assert_allclose(0.5 * np.sum(res.fun**2), float(sm.cost), rtol=1e-10)


# --- SE_2(3): the inertial navigation against an independent solve ---------------------------------------------
def _so3_hat(w):
    o = jnp.zeros_like(w[..., 0])
    return jnp.stack([jnp.stack([o, -w[..., 2], w[..., 1]], -1), jnp.stack([w[..., 2], o, -w[..., 0]], -1),
                      jnp.stack([-w[..., 1], w[..., 0], o], -1)], -2)


def _so3_exp_and_jacobian(phi):
    """Rodrigues' rotation and SO(3)'s left Jacobian, (..., 3, 3) each, with their series near zero."""
    th2 = jnp.sum(phi**2, -1)
    small = th2 < 1e-8
    t2 = jnp.where(small, 1.0, th2)
    t = jnp.sqrt(t2)
    a = jnp.where(small, 1.0 - th2 / 6.0, jnp.sin(t) / t)[..., None, None]
    b = jnp.where(small, 0.5 - th2 / 24.0, (1.0 - jnp.cos(t)) / t2)[..., None, None]
    c = jnp.where(small, 1.0 / 6.0 - th2 / 120.0, (t - jnp.sin(t)) / (t2 * t))[..., None, None]
    W = _so3_hat(phi)
    return jnp.eye(3) + a * W + b * W @ W, jnp.eye(3) + b * W + c * W @ W


def _so3_log(R):
    w = 0.5 * jnp.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s2 = jnp.sum(w**2, -1)
    small = s2 < 1e-16
    s = jnp.sqrt(jnp.where(small, 1.0, s2))
    th = jnp.arctan2(s, 0.5 * (jnp.trace(R, axis1=-2, axis2=-1) - 1.0))
    return w * jnp.where(small, 1.0 + s2 / 6.0, th / s)[..., None]


def _se23_matrices(R, v, p):
    """SE_2(3) matrices (..., 5, 5): [[R, v, p], [0, 1, 0], [0, 0, 1]]."""
    top = jnp.concatenate([R, v[..., None], p[..., None]], -1)
    bottom = jnp.concatenate([jnp.zeros(R.shape[:-2] + (2, 3)), jnp.broadcast_to(jnp.eye(2), R.shape[:-2] + (2, 2))],
                             -1)
    return jnp.concatenate([top, bottom], -2)


def _se23_exp(xi):
    R, J = _so3_exp_and_jacobian(xi[..., :3])
    return _se23_matrices(R, jnp.einsum("...ij,...j->...i", J, xi[..., 3:6]),
                          jnp.einsum("...ij,...j->...i", J, xi[..., 6:9]))


def _se23_log(X):
    """SE_2(3)'s log (..., 9) in liemef's order (omega, nu_v, nu_p): Log R, then J(Log R)^-1 (v, p)."""
    phi = _so3_log(X[..., :3, :3])
    nu = jnp.linalg.solve(_so3_exp_and_jacobian(phi)[1], X[..., :3, 3:5])
    return jnp.concatenate([phi, nu[..., 0], nu[..., 1]], -1)


def test_inertial_smoother_is_scipy_least_squares_on_se23():
    """ukfm's inertial navigation (IMU-driven SE_2(3) with gravity, three landmarks seen every 0.25 s), 1 s at
    100 Hz: the same cost written again without liemef's groups or systems (5 x 5 matrices, Rodrigues' formula
    and a closed-form log; the kinematics (omega, a + R^T g, R^T v) held over each interval; each landmark
    R^T (l - p) in the body frame; the stds floored at 1e-6 as the smoother floors them, here the position's
    process noise, which the model leaves at zero), each state by its rotation vector, velocity and position,
    minimized by scipy's least squares from a start off the smoother's minimizer: the same minimizer to 1e-8,
    and the same cost."""
    c = ins.InertialConfig(duration=1.0, obs_period=0.25, steady=0.0)
    setup = ins.setup(c)
    system = setup.system
    flt = liemef.MinimumEnergyFilter(system)
    log, g0 = ins.sensor_log(c, setup.truth, setup.u_true, ins.jax_draws(c, jax.random.key(3)))
    K0 = np.diag([c.rot0_std**2] * 3 + [0.05**2] * 3 + [c.p0_std**2] * 3)
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    sm = liemef.smooth(flt, flt.init(g0, K0=K0), ts, us, ys, integrator="lie-euler", tol=1e-12)
    assert sm.ok, sm.message
    N = ts.size
    B, R = np.asarray(system.B), np.asarray(system.R)
    Qd = B @ np.linalg.solve(R, B.T) * c.dt
    assert np.array_equal(Qd, np.diag(np.diag(Qd))) and np.any(np.diag(Qd) == 0.0)
    Lq = np.diag(np.maximum(np.diag(Qd), _batch.FLOOR_STD**2) ** -0.5)
    L0 = np.diag(np.diag(K0) ** -0.5)
    Lm = np.linalg.cholesky(np.asarray(system.information())).T
    G0 = np.asarray(g0.as_matrix())
    seen = np.flatnonzero(np.isfinite(ys[:, 0]))
    landmarks, gravity = np.asarray(c.landmarks), np.array([0.0, 0.0, -c.gravity])
    gyro, acc = us[:-1, :3], us[:-1, 3:]

    def states(z):
        z = z.reshape(N, 9)
        return _se23_matrices(_so3_exp_and_jacobian(z[:, :3])[0], z[:, 3:6], z[:, 6:9])

    def residuals(z):
        X = states(z)
        Rt = jnp.swapaxes(X[:-1, :3, :3], -1, -2)
        kinematics = jnp.concatenate([gyro, acc + Rt @ gravity, jnp.einsum("kij,kj->ki", Rt, X[:-1, :3, 3])], -1)
        flow = X[:-1] @ _se23_exp(kinematics * c.dt)
        r0 = L0 @ _se23_log(jnp.linalg.solve(G0, X[0]))
        rp = _se23_log(jnp.linalg.solve(flow, X[1:])) @ Lq.T
        Rs, ps = X[seen, :3, :3], X[seen, :3, 4]
        h = jnp.einsum("kji,klj->kli", Rs, landmarks[None] - ps[:, None]).reshape(seen.size, -1)
        return jnp.concatenate([r0, rp.ravel(), ((ys[seen] - h) @ Lm.T).ravel()])

    jacobian, residuals = jax.jit(jax.jacfwd(residuals)), jax.jit(residuals)
    M = np.asarray(sm.g.as_matrix())
    z_sm = np.concatenate([np.asarray(_so3_log(jnp.asarray(M[:, :3, :3]))), M[:, :3, 3], M[:, :3, 4]], -1).ravel()
    res = optimize.least_squares(lambda z: np.asarray(residuals(z)), z_sm + 1e-3,
                                 jac=lambda z: np.asarray(jacobian(z)), method="lm", xtol=1e-15, ftol=1e-15,
                                 gtol=1e-15)
    X = np.asarray(states(jnp.asarray(res.x)))
    print(f"inertial smoother against least squares: {np.max(np.abs(X - M)):.2e}")
    np.testing.assert_allclose(X, M, atol=LSQ)
    np.testing.assert_allclose(0.5 * np.sum(res.fun**2), float(sm.cost), rtol=1e-10)


def test_marginal_covariances_are_blocks_of_the_inverse_hessian(localization):
    """The marginal covariances of the backward recursion equal the diagonal blocks of the inverse of the whole
    Gauss-Newton Hessian, formed densely from the Jacobian of every residual at once (autodiff of the stacked
    residuals, not the block-tridiagonal assembly), on the first 40 states."""
    c, truth, system, flt, K0 = localization
    log, g0 = loc.sensor_log(c, truth, loc.jax_draws(c, jax.random.key(6)))
    ts, us, ys = (np.asarray(a)[:40] for a in (log.ts, log.us, log.ys))
    sm = liemef.smooth(flt, flt.init(g0, K0=K0), ts, us, ys)
    assert sm.ok, sm.message
    integ = flt.integrator
    prob, xs = _batch.problem(system, flt.weights, ts, _batch._held(us, np.zeros(3)), ys, g0, K0, init=sm.g,
                              integ=integ)
    M, n = prob.ts.shape[0], 3

    def whitened(d):
        x = xs.rplus(d.reshape(M, n))
        r0 = x[0].rminus(prob.g0)
        rp = jax.vmap(lambda a, b, u, t, h: b.rminus(_batch._flow(system, integ, a, u, t, h)))(
            x[:-1], x[1:], prob.us[:-1], prob.ts[:-1], prob.dts)
        rm = jax.vmap(lambda a, y, t: system.output_seen_from(y, a, t) - y)(x, prob.ys, prob.ts)
        rm = jnp.where(prob.present, rm, 0.0)
        chol = lambda S: jnp.linalg.cholesky(S + 1e-300 * jnp.eye(S.shape[-1])).swapaxes(-1, -2)  # noqa: E731
        wm = jnp.einsum("kij,kj->ki", jnp.linalg.cholesky(prob.W + jnp.eye(2) * 1e-30).swapaxes(-1, -2), rm)
        return jnp.concatenate([chol(prob.P0inv) @ r0, jnp.einsum("kij,kj->ki", chol(prob.Qinv), rp).ravel(),
                                wm.ravel()])

    J = np.asarray(jax.jit(jax.jacfwd(whitened))(jnp.zeros(M * n)))
    H = J.T @ J
    Sigma = np.linalg.inv(H)
    N = ts.size
    blocks = np.stack([Sigma[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k in range(N)])
    print(f"dense Hessian: cond {np.linalg.cond(H):.1e}")
    np.testing.assert_allclose(np.asarray(sm.P), blocks, rtol=1e-9, atol=1e-14)


def test_smoother_is_consistent_by_monte_carlo(localization):
    """40 runs with seeded draws: the smoothed error's NEES, averaged over the runs, lies in its 95 % band at
    least 90 % of the time; and the smoother's error is below the filter's on average."""
    c, truth, system, flt, K0 = localization
    runs = 40
    nees, err_s, err_f = [], [], []
    for i in range(runs):
        ts, us, ys, g0, sm = _localization_run(localization, jax.random.key(100 + i))
        assert sm.ok, sm.message
        e = np.asarray(jax.vmap(lambda a, b: a.rminus(b))(truth, sm.g))  # log(g_hat^-1 g)
        nees.append(np.einsum("ki,kij,kj->k", e, np.linalg.inv(np.asarray(sm.P)), e))
        err_s.append(np.linalg.norm(e[:, 1:], axis=1))
        traj = flt.run(flt.init(g0, K0=K0), ts, us, ys)
        assert bool(traj.ok), traj.status.message()
        ef = np.asarray(jax.vmap(lambda a, b: a.rminus(b))(truth, traj.g_hat))
        err_f.append(np.linalg.norm(ef[:, 1:], axis=1))
    mean = np.mean(nees, axis=0)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * runs) / runs
    inside = np.mean((mean >= lo) & (mean <= hi))
    print(f"smoother NEES: mean {mean.mean():.3f} (dof 3), inside its band {inside:.2f}")
    assert inside >= 0.9
    print(f"position error: smoother {np.mean(err_s):.4g} m, filter {np.mean(err_f):.4g} m")
    assert np.mean(err_s) < np.mean(err_f)


# --- robust losses --------------------------------------------------------------------------------------------
def _robust_system(robust):
    return SensorSystem(Rn[2], _linear, (Sensor("pos", _position, Noise.sample(SIGMA), robust=robust),),
                        Noise.density(Q_DENSITY), inputs=("a",))


@pytest.mark.parametrize("robust", ["huber", "cauchy"])
def test_robust_gradient_is_the_robust_costs(robust):
    """The reweighted gradient (each sensor's information times rho'(s)) is the autodiff gradient of the robust
    cost, at a trajectory off the minimum with residuals in both branches of Huber's loss."""
    system, ts, us, ys = _linear_log("sample")
    system = _robust_system(robust)
    ys = ys.copy()
    ys[3, 0] = 8.0  # an outlier
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    integ = flt.integrator
    init = Rn[2](np.random.default_rng(0).standard_normal((ts.size, 2)))
    prob, xs = _batch.problem(system, flt.weights, ts, us, ys, Rn[2](np.zeros(2)), np.eye(2), init=init,
                              integ=integ)
    screens = _batch._screens(system)
    _, _, gr, f = _batch._linearize(system, integ, screens, prob, xs)
    M = prob.ts.shape[0]
    cost = lambda d: _batch._cost(system, integ, screens, prob, xs.rplus(d.reshape(M, 2)))  # noqa: E731
    np.testing.assert_allclose(float(f), float(cost(jnp.zeros(2 * M))), rtol=1e-14)
    np.testing.assert_allclose(np.asarray(gr).ravel(), np.asarray(jax.grad(cost)(jnp.zeros(2 * M))), atol=1e-10)


def test_robust_loss_resists_an_outlier():
    """A 50 sigma outlier pulls the Gaussian smoother's estimate at its time; Huber's loss keeps it near the
    estimate without the outlier."""
    system, ts, us, ys = _linear_log("sample")
    bad = ys.copy()
    bad[6, 0] = 20.0
    x0, P0 = np.zeros(2), np.eye(2)

    def smoothed(sys_, y):
        flt = liemef.MinimumEnergyFilter(sys_, integrator="lie-euler")
        sm = liemef.smooth(flt, flt.init(Rn[2](x0), K0=P0), ts, us, y)
        assert sm.ok, sm.message
        return np.asarray(sm.g.x), sm.iterations

    clean, _ = smoothed(system, ys)
    gauss, _ = smoothed(system, bad)
    huber, iterations = smoothed(_robust_system("huber"), bad)
    # Newton with the robust term's own Hessian: a few steps (reweighting alone, rho' W, converges linearly: it
    # was still moving after 12)
    assert iterations <= 6, iterations
    assert abs(gauss[6, 0] - clean[6, 0]) > 1.0
    assert abs(huber[6, 0] - clean[6, 0]) < 0.2 * abs(gauss[6, 0] - clean[6, 0])


# --- failures and bad input -----------------------------------------------------------------------------------
def _blows_up(g, u, t):
    return jnp.where(t > 0.5, jnp.nan, 0.0) * g.x


def test_a_non_finite_cost_is_a_failed_status_with_nan_estimates():
    system = System(group_type=Rn[2], dynamics_fn=_blows_up, output_fn=lambda g, t: g.x, B=np.eye(2), D=np.eye(2),
                    Q=np.eye(2), R=np.eye(2))
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    ts = np.arange(30) * 0.05
    ys = np.ones((30, 2))
    sm = liemef.smooth(flt, flt.init(Rn[2](np.zeros(2)), K0=np.eye(2)), ts, None, ys, init=Rn[2](np.zeros((30, 2))))
    assert sm.status == "failed" and not sm.ok
    assert "not finite" in sm.message
    assert bool(jnp.all(jnp.isnan(sm.g.x))) and bool(jnp.all(jnp.isnan(sm.P)))


def test_too_few_iterations_is_said(localization):
    """One step from a start far from the minimizer on SE(2) does not converge, and the status says so; the
    estimate it has is finite and no costlier than the start (the localization's filter and log length, with
    fixes far from its path)."""
    c, _, _, flt, _ = localization
    ts = np.asarray(c.ts)
    us = np.tile(np.asarray(loc.true_input(c)), (ts.size, 1))
    ys = np.full((ts.size, 2), np.nan)
    ys[25::25] = [[3.0, 2.0]]
    state = flt.init(SE2.identity(), K0=np.diag([1.0, 1e-2, 1e-2]))
    sm = liemef.smooth(flt, state, ts, us, ys, max_iterations=1)
    assert sm.status == "max-iterations" and not sm.ok and "not converged" in sm.message
    assert bool(jnp.all(jnp.isfinite(sm.g.coords())))
    assert float(sm.cost) <= float(sm.cost_init)
    full = liemef.smooth(flt, state, ts, us, ys)
    assert full.ok and full.iterations > 1 and float(full.cost) < float(sm.cost)


def test_a_failed_filter_pass_is_replaced_by_dead_reckoning():
    """Where the filter's own pass fails (NaN states after the failure), the smoother starts from dead reckoning
    there, and still converges to the RTS answer."""
    system, ts, us, ys = _linear_log("sample")
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    init = np.zeros((ts.size, 2))
    init[20:] = np.nan
    filled = _batch._filled(system, flt.integrator, Rn[2](init), ts, us)
    assert bool(jnp.all(jnp.isfinite(filled.x)))
    sm = liemef.smooth(flt, flt.init(Rn[2](np.zeros(2)), K0=np.eye(2)), ts, us, ys, init=Rn[2](init))
    ref = liemef.smooth(flt, flt.init(Rn[2](np.zeros(2)), K0=np.eye(2)), ts, us, ys)
    assert sm.ok
    np.testing.assert_allclose(np.asarray(sm.g.x), np.asarray(ref.g.x), atol=1e-9)


def test_bad_arguments_are_named():
    system, ts, us, ys = _linear_log("sample")
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    state = flt.init(Rn[2](np.zeros(2)), K0=np.eye(2))
    with pytest.raises(ValueError, match="flt: expected a liemef filter"):
        liemef.smooth(system, state, ts, us, ys)
    with pytest.raises(ValueError, match=r"max_iterations: expected an integer >= 1 and <= \d+, got 0"):
        liemef.smooth(flt, state, ts, us, ys, max_iterations=0)
    with pytest.raises(ValueError, match="tol"):
        liemef.smooth(flt, state, ts, us, ys, tol=-1.0)
    with pytest.raises(ValueError, match="floor_std: expected a finite number > 0, got 0.0"):
        liemef.smooth(flt, state, ts, us, ys, floor_std=0.0)
    with pytest.raises(ValueError, match=r"init: expected a Rn\[2\]|init: expected a R2"):
        liemef.smooth(flt, state, ts, us, ys, init=Rn[2](np.zeros((3, 2))))
    with pytest.raises(ValueError, match="ys"):
        liemef.smooth(flt, state, ts, us, ys[:, :0])


# --- fixed lag ------------------------------------------------------------------------------------------------
def test_fixed_lag_on_a_linear_system_is_rts_of_the_log_so_far():
    """With the invariant EKF as the filter (on R^n the discrete Kalman filter of the same Euler model), each
    window of the fixed-lag smoother is the RTS smoother of the log cut at the window's newest sample, over the
    window's states, to 1e-10: the filter's state at the window's start is the exact prior of the samples
    before it. Missing samples included; the window warm-starts from the last one."""
    from liemef.filters.baselines import invariant_ekf

    system, ts, us, ys = _linear_log("sample")
    x0, P0 = np.array([0.5, -0.3]), np.diag([1.0, 2.0])
    flt = invariant_ekf(system)
    lag = 6
    fl = liemef.smoothers.FixedLagSmoother(flt, flt.init(Rn[2](x0), K0=P0), lag, integrator="lie-euler")
    R = [np.array([[SIGMA**2]])] * ts.size
    windows = 0
    for e in range(ts.size):
        w = fl.update(ts[e], us[e], ys[e])
        if e < lag:
            assert w is None
            continue
        assert w.ok, w.message
        xs, Ps = _rts(ts[:e + 1], us[:e + 1], ys[:e + 1], x0, P0, R[:e + 1], np.diag(Q_DENSITY**2) * DT)
        np.testing.assert_allclose(np.asarray(w.ts), ts[e - lag:e + 1])
        np.testing.assert_allclose(np.asarray(w.g.x), xs[e - lag:], atol=RTS)
        np.testing.assert_allclose(np.asarray(w.P), Ps[e - lag:], atol=RTS)
        windows += 1
    assert windows == ts.size - lag


def test_fixed_lag_bad_arguments_and_a_failed_filter():
    system, ts, us, ys = _linear_log("sample")
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    state = flt.init(Rn[2](np.zeros(2)), K0=np.eye(2))
    with pytest.raises(ValueError, match="lag: expected a number of samples >= 1, got 0"):
        liemef.smoothers.FixedLagSmoother(flt, state, 0)
    fl = liemef.smoothers.FixedLagSmoother(flt, state, 2)
    fl.update(0.0, us[0], ys[0])
    with pytest.raises(ValueError, match="t: expected a time after the previous sample's 0.0, got 0.0"):
        fl.update(0.0, us[1], ys[1])
    with pytest.raises(ValueError, match="y"):
        fl.update(0.1, us[1], ys[1, :0])
    # a filter that fails (a non-finite input): the window that would take its prior says so, with NaN estimates
    system_nan = System(group_type=Rn[2], dynamics_fn=_blows_up, output_fn=lambda g, t: g.x, B=np.eye(2),
                        D=np.eye(2), Q=np.eye(2), R=np.eye(2))
    bad = liemef.MinimumEnergyFilter(system_nan, integrator="lie-euler")
    fl = liemef.smoothers.FixedLagSmoother(bad, bad.init(Rn[2](np.zeros(2)), K0=np.eye(2)), 2)
    out = [fl.update(0.2 * k, None, np.ones(2)) for k in range(8)]
    assert out[-1].status == "failed" and "the filter that gives the window's prior failed" in out[-1].message
    assert bool(jnp.all(jnp.isnan(out[-1].g.x)))


# --- in chunks ------------------------------------------------------------------------------------------------
def test_windows_cover_the_log_once_and_hold_their_blocks():
    for N, chunk, before, after in [(41, 7, 2, 3), (43, 7, 0, 0), (8, 7, 0, 0), (5, 100, 3, 3), (2, 1, 0, 0)]:
        ws = liemef.smoothers._chunks.windows(N, chunk, before, after)
        assert [a for a, *_ in ws] == sorted({a for a, *_ in ws}) and ws[0][0] == 0 and ws[-1][1] == N
        assert all(ws[i][1] == ws[i + 1][0] for i in range(len(ws) - 1))  # consecutive blocks, each state once
        for a, b, s, e in ws:
            assert s <= a < b <= e + 1 and e - s >= 1 and 0 <= s and e <= N - 1
            assert s == max(0, a - before) or (before == 0 and b - a == 1)


def test_chunks_whose_windows_run_to_the_end_are_rts_on_a_linear_system():
    """On the linear system with the invariant EKF (on R^n the discrete Kalman filter of the smoother's Euler
    model), blocks of 7 states whose windows start at the block and run to the log's end are the RTS smoother's
    estimates and covariances to 1e-10: each window's prior, the filter's state at its first time, is the exact
    Gaussian of the samples before it. The joined cost is the whole log's: that of the whole-log smoother, and
    at the filter's pass its cost_init. smooth_chunks yields the same blocks one by one."""
    from liemef.filters.baselines import invariant_ekf

    system, ts, us, ys = _linear_log("sample")
    x0, P0 = np.array([0.5, -0.3]), np.diag([1.0, 2.0])
    flt = invariant_ekf(system)
    state = flt.init(Rn[2](x0), K0=P0)
    N = ts.size
    xs, Ps = _rts(ts, us, ys, x0, P0, [np.array([[SIGMA**2]])] * N, np.diag(Q_DENSITY**2) * DT)
    ch = liemef.smooth(flt, state, ts, us, ys, integrator="lie-euler", chunk=7, overlap=(0, N))
    assert ch.ok, ch.message
    assert ch.message.startswith("converged: 6 windows of 7 states with overlaps 0 before and 41 after")
    np.testing.assert_allclose(np.asarray(ch.ts), ts)
    np.testing.assert_allclose(np.asarray(ch.g.x), xs, atol=RTS)
    np.testing.assert_allclose(np.asarray(ch.P), Ps, atol=RTS)
    whole = liemef.smooth(flt, state, ts, us, ys, integrator="lie-euler")
    np.testing.assert_allclose(float(ch.cost), float(whole.cost), rtol=1e-12)
    np.testing.assert_allclose(float(ch.cost_init), float(whole.cost_init), rtol=1e-12)
    blocks = list(liemef.smoothers.smooth_chunks(flt, state, ts, us, ys, integrator="lie-euler", chunk=7,
                                                  overlap=(0, N)))
    assert [b.ts.shape[0] for b in blocks] == [7] * 5 + [6] and all(b.ok for b in blocks)
    np.testing.assert_array_equal(np.concatenate([np.asarray(b.g.x) for b in blocks]), np.asarray(ch.g.x))
    assert "window of samples 7..40 (states 7..13)" in blocks[1].message


def test_chunks_approach_the_whole_log_smoother_as_the_overlap_grows(localization):
    """On SE(2) localization (a 10 deg initial heading error, a fix every 0.25 s), blocks of 50 of the 200 states:
    the windows leave out the samples after them and linearize their prior at the filter's estimate, so the
    joined estimate costs more than the whole-log minimizer, and both that excess and the distance to the
    minimizer fall as the overlap grows."""
    c, truth, system, flt, K0 = localization
    log, g0 = loc.sensor_log(c, truth, loc.jax_draws(c, jax.random.key(9)))
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    state = flt.init(g0, K0=K0)
    whole = liemef.smooth(flt, state, ts, us, ys)
    assert whole.ok

    def off(sm):
        d = np.asarray(sm.g.coords()) - np.asarray(whole.g.coords())
        d[:, 0] = np.angle(np.exp(1j * d[:, 0]))
        return np.abs(d).max(), float(sm.cost) - float(whole.cost)

    near = [off(liemef.smooth(flt, state, ts, us, ys, chunk=50, overlap=o)) for o in (25, 100)]
    assert all(excess > 0 for _, excess in near)  # the whole-log smoother is the minimizer
    assert near[1][0] < 0.2 * near[0][0] and near[1][1] < 0.05 * near[0][1], near
    assert near[1][0] < 0.05, near


def test_chunks_say_when_a_window_has_no_prior_and_refuse_bad_options():
    system, ts, us, ys = _linear_log("sample")
    flt = liemef.MinimumEnergyFilter(system, integrator="lie-euler")
    state = flt.init(Rn[2](np.zeros(2)), K0=np.eye(2))
    for kwargs, match in [(dict(chunk=0), "chunk: expected an integer >= 1"),
                          (dict(chunk=5, overlap=-1), "overlap: expected an integer >= 0"),
                          (dict(chunk=5, overlap=(1, -2)), r"overlap\[1\]: expected an integer >= 0"),
                          (dict(chunk=5, overlap=(1, 2, 3)), r"overlap: expected a number of samples or a pair"),
                          (dict(overlap=3), "overlap: only with chunk"),
                          (dict(chunk=2.5), "chunk: expected an integer")]:
        with pytest.raises(ValueError, match=match):
            liemef.smooth(flt, state, ts, us, ys, **kwargs)
    with pytest.raises(ValueError, match="chunk: expected an integer >= 1"):
        liemef.smoothers.smooth_chunks(flt, state, ts, us, ys, chunk=0)
    # dynamics that are NaN after t = 5 s: the blocks before are smoothed, the windows whose states (or padding)
    # reach past it fail, and those after the filter's failure have no prior; the joined run fails with NaN
    # estimates
    system_nan = System(group_type=Rn[2], dynamics_fn=lambda g, u, t: jnp.where(t > 5.0, jnp.nan, 0.0) * g.x,
                        output_fn=lambda g, t: g.x, B=np.eye(2), D=np.eye(2), Q=np.eye(2), R=np.eye(2))
    bad = liemef.MinimumEnergyFilter(system_nan, integrator="lie-euler")
    args = (bad, bad.init(Rn[2](np.zeros(2)), K0=np.eye(2)), np.arange(200) * 0.05, None, np.ones((200, 2)))
    blocks = list(liemef.smoothers.smooth_chunks(*args, chunk=30, overlap=0))
    assert [b.status for b in blocks] == ["converged"] * 2 + ["failed"] * 5
    assert "the cost is not finite" in blocks[2].message
    assert "the filter that gives the window's prior failed at sample 101" in blocks[-1].message
    assert bool(jnp.all(jnp.isnan(blocks[-1].g.x))) and bool(jnp.all(jnp.isfinite(blocks[1].g.x)))
    sm = liemef.smooth(*args, chunk=30, overlap=0)
    assert sm.status == "failed" and "states 60..89" in sm.message
    assert bool(jnp.all(jnp.isnan(sm.g.x))) and bool(jnp.all(jnp.isnan(sm.P)))


# --- behind a filter's run -------------------------------------------------------------------------------------
def test_offline_smoother_runs_as_a_filter_and_fails_as_one(localization):
    """OfflineSmoother's run is the smoother's estimates and covariances as a Trajectory; one that does not
    converge is a failed status (cause "not converged") with NaN states after the first, as a failed filter run."""
    from liemef.filters import CAUSES

    c, truth, system, flt, K0 = localization
    log, g0 = loc.sensor_log(c, truth, loc.jax_draws(c, jax.random.key(9)))
    ts, us, ys = (np.asarray(a) for a in (log.ts, log.us, log.ys))
    state = flt.init(g0, K0=K0)
    ref = liemef.smooth(flt, state, ts, us, ys)
    off = liemef.smoothers.OfflineSmoother(flt)
    traj = off.run(off.init(g0, K0=K0), ts, us, ys)
    assert traj.ok and off.offline
    np.testing.assert_array_equal(np.asarray(traj.g_hat.coords()), np.asarray(ref.g.coords()))
    np.testing.assert_array_equal(np.asarray(traj.K), np.asarray(ref.P))
    short = liemef.smoothers.OfflineSmoother(flt, max_iterations=1).run(state, ts, us, ys)
    assert not short.ok and int(short.status.code) == CAUSES.NOT_CONVERGED.code
    assert "did not converge" in short.status.message(ts)
    assert bool(jnp.all(jnp.isnan(short.g_hat.coords()[1:]))) and bool(jnp.all(jnp.isfinite(short.g_hat.coords()[0])))
