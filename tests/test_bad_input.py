"""Bad input gets a ValueError naming the argument, what was expected and what came, before compiled code runs."""

import re

import numpy as np
import pytest

import liemef
from liemef.groups import SE2, TSE2, TSO3, Rn
from liemef.systems import PlanarRigidBody, System, tse2_state


@pytest.fixture(scope="module")
def flt():
    return liemef.MinimumEnergyFilter(PlanarRigidBody())


@pytest.fixture(scope="module")
def state(flt):
    return flt.init(tse2_state(0.1, 1.0, 2.0, 0.0, 0.0, 0.0), np.eye(6))


def raises(match):
    return pytest.raises(ValueError, match=match)


# --- systems
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(D=np.eye(3)), r"D: expected shape \(7, 7\).*got \(3, 3\)"),
        (dict(D=np.diag([0.5, 0.5, 0.5, 0.0, 0.1, 0.1, 0.1])), r"D: expected an invertible matrix.*singular value"),
        (dict(Q=-np.eye(7)), r"Q: expected a positive definite matrix, got smallest eigenvalue -1"),
        (dict(Q=np.eye(7) + np.triu(np.ones((7, 7)), 1)), r"Q: expected a symmetric matrix"),
        (dict(R=np.diag([1.0, 0.0, 1.0])), r"R: expected a positive definite matrix, got smallest eigenvalue 0"),
        (dict(R=np.eye(2)), r"R: expected shape \(3, 3\), got \(2, 2\)"),
        (dict(B=np.ones((5, 3))), r"B: expected shape \(6, N\), got \(5, 3\)"),
        (dict(B=np.full((6, 3), np.nan)), r"B: expected finite values, got nan"),
        (dict(sensor="lidar"), r"sensor: expected one of \['gps_imu', 'velocity'\], got 'lidar'"),
    ],
)
def test_system_rejects(kwargs, match):
    with raises(match):
        PlanarRigidBody(**kwargs)


def test_user_system_dynamics_shape():
    with raises(r"dynamics test_user_system_dynamics_shape.<locals>.<lambda> \(test_bad_input.py, line \d+\): "
                r"expected shape \(3,\) \(lambda\(g, u, t\): one value per direction of the algebra of R3\), "
                r"got shape \(2,\)"):
        System(group_type=Rn[3], dynamics_fn=lambda g, u, t: g.x[:2], output_fn=lambda g, t: g.x,
               B=np.eye(3), D=np.eye(3), Q=np.eye(3), R=np.eye(3))


# --- filter construction
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(connection="torsionfree"), r"connection: expected one of \['minus', 'plus', 'zero'\].*'torsionfree'"),
        (dict(order="third"), r"order: expected one of \['first', 'second'\], got 'third'"),
        (dict(integrator="rk45"), r"integrator: expected one of .*'rkmk4'.*got 'rk45'"),
        (dict(alpha=-0.1), r"alpha: expected a number >= 0, got -0.1"),
        (dict(alpha=float("nan")), r"alpha: expected finite values, got nan"),
    ],
)
def test_filter_rejects(kwargs, match):
    with raises(match):
        liemef.MinimumEnergyFilter(PlanarRigidBody(), **kwargs)


def test_filter_rejects_non_system():
    with raises(r"system: expected a liemef system \(AbstractSystem\), got dict"):
        liemef.MinimumEnergyFilter({"group": TSE2})


# --- init
@pytest.mark.parametrize(
    ("K0", "match"),
    [
        (-np.eye(6), r"K0: expected a positive semidefinite matrix, got smallest eigenvalue -1"),
        (np.eye(5), r"K0: expected shape \(6, 6\), got \(5, 5\)"),
        (np.diag([1.0, 1, 1, 1, 1, np.inf]), r"K0: expected finite values, got inf at index \(5, 5\)"),
        (np.eye(6) + np.eye(6, k=1), r"K0: expected a symmetric matrix"),
    ],
)
def test_init_rejects_gain(flt, K0, match):
    with raises(match):
        flt.init(tse2_state(0, 0, 0, 0, 0, 0), K0)


def test_init_accepts_singular_gain(flt):
    # Rigo et al. 2023, eq. (63): a positive semidefinite K0 with a zero row and column is legitimate
    K0 = np.eye(6)
    K0[2, 2] = 0.0
    assert np.array_equal(np.asarray(flt.init(tse2_state(0, 0, 0, 0, 0, 0), K0).K), K0)


def test_init_from_hessian(flt):
    X0 = np.diag([2.0, 1, 1, 1, 1, 4])
    K = np.asarray(flt.init(tse2_state(0, 0, 0, 0, 0, 0), X0=X0).K)
    np.testing.assert_allclose(K, np.diag([0.5, 1, 1, 1, 1, 0.25]), rtol=0, atol=1e-15)
    with raises(r"X0: expected a positive definite matrix, got smallest eigenvalue 0"):
        flt.init(tse2_state(0, 0, 0, 0, 0, 0), X0=np.diag([0.0, 1, 1, 1, 1, 1]))
    with raises(r"init: expected exactly one of K0 \(initial gain\) or X0 \(Hessian of m0\), got both"):
        flt.init(tse2_state(0, 0, 0, 0, 0, 0), np.eye(6), X0=X0)
    with raises(r"got neither"):
        flt.init(tse2_state(0, 0, 0, 0, 0, 0))


def test_init_rejects_wrong_group_and_batches(flt):
    with raises(r"g0: expected an element of SE2xR3, got SO3xR3"):
        flt.init(TSO3.identity(), np.eye(6))
    with raises(r"g0: expected a single element \(no batch axes\), got batch shape \(2,\)"):
        flt.init(TSE2.identity((2,)), np.eye(6))
    with raises(r"g0: expected finite values, got nan"):
        flt.init(tse2_state(np.nan, 0, 0, 0, 0, 0), np.eye(6))


# --- step and run
def test_step_rejects(flt, state):
    u, y = np.zeros(2), np.zeros(7)
    with raises(r"y: expected shape \(7,\), got \(6,\)"):
        flt.step(state, 0.0, u, np.zeros(6), 1e-3)
    with raises(r"u: expected finite values or NaN \(missing\), got inf at index \(1,\)"):
        flt.step(state, 0.0, np.array([0.0, np.inf]), y, 1e-3)  # NaN is a missing sample (held); inf is not
    with raises(r"dt: expected a finite time step > 0, got 0.0"):
        flt.step(state, 0.0, u, y, 0.0)
    with raises(r"t: expected a finite time, got inf"):
        flt.step(state, np.inf, u, y, 1e-3)
    with raises(r"state: expected a FilterState \(from init or step\), got tuple"):
        flt.step((state.g_hat, state.K), 0.0, u, y, 1e-3)


def test_run_rejects(flt, state):
    N = 5
    ts, us, ys = np.arange(N) * 0.01, np.zeros((N, 2)), np.zeros((N, 7))
    with raises(r"ts: expected strictly increasing time stamps, got t\[2\] = 0.02 followed by t\[3\] = 0.02"):
        flt.run(state, np.array([0.0, 0.01, 0.02, 0.02, 0.03]), us, ys)
    with raises(r"ys: expected shape \(5, 7\), got \(4, 7\)"):
        flt.run(state, ts, us, ys[:4])
    with raises(r"us: expected shape \(5, 2\), got \(5, 3\)"):
        flt.run(state, ts, np.zeros((N, 3)), ys)
    bad = ys.copy()
    bad[3, 4] = np.inf
    with raises(r"ys: expected finite values or NaN \(missing\), got inf at index \(3, 4\)"):
        flt.run(state, ts, us, bad)
    with raises(r"ts: expected at least 2 time stamps, got 1"):
        flt.run(state, ts[:1], us[:1], ys[:1])
    with raises(r"ts: expected a numeric array, got str"):
        flt.run(state, "abc", us, ys)


def test_terms_rejects(flt, state):
    with raises(re.escape("K: expected shape (6, 6), got (3, 3)")):
        flt.terms(state.g_hat, np.eye(3), np.zeros(2), np.zeros(7))
    with raises(r"g_hat: expected an element of SE2xR3, got SE2"):
        flt.terms(SE2.identity(), np.eye(6), np.zeros(2), np.zeros(7))


def test_filter_is_immutable(flt):
    with pytest.raises(AttributeError, match="frozen|immutable|cannot"):
        flt.alpha = 1.0


@pytest.mark.parametrize("scale", [1.008, 2.0, 0.0])
@pytest.mark.parametrize("make", ["pose3d", "inertial_navigation"])
def test_init_refuses_a_3d_state_off_the_group(make, scale):
    """SE(3) and SE_2(3) states whose quaternion is not a unit one (|q| = 1.008, 2 or 0, the last of which once
    ran "ok" with NaN coordinates for a whole log) are refused at init, naming g0 and the distance."""
    import jax.numpy as jnp

    from liemef import systems

    system = getattr(systems, make)()
    G = system.group
    good = G.identity()
    bad = G(jnp.concatenate([scale * good.wxyz_p[:4], good.wxyz_p[4:] + 0.5]))
    flt = liemef.MinimumEnergyFilter(system)
    flt.init(good, np.eye(flt.n))  # a unit quaternion passes
    with pytest.raises(ValueError, match=rf"g0: expected an element of {G.__name__} within .* got one "
                                          rf"{abs(scale - 1.0):.6g} off the group"):
        flt.init(bad, np.eye(flt.n))
