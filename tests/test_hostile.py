"""Hostile input at the Python API (issue 19, item 2): every bad input is a ValueError, raised before any compile,
whose message names the argument (or the file) and the value received; a hostile log that is valid input ends
in a finite estimate with its warnings or in a failure value.

Categories: log files, group elements, physical parameters, dtypes, integer ranges, system files, encodings
and gains/times of ``terms``, and hostile logs at run time (a NaN input, an outlier, a gap, a huge K0: a finite
estimate with its warnings or a failure value). The tolerance for group elements is
``liemef._validate.ON_GROUP``. Each category is a section opened by ``# --- name ---``;
``python tools/hostile_counts.py`` counts the cases per category.
"""

from __future__ import annotations

import re
import zipfile

import jax.numpy as jnp
import numpy as np
import pytest

import liemef
from liemef import _validate
from liemef.groups import SE2, SO3, TSE2, Rn
from liemef.reports import io
from liemef.simulation import simulate
from liemef.studies.experiments import tse2
from liemef.studies.experiments._montecarlo import trial_keys
from liemef.systems import ChaplyginSleigh, PlanarRigidBody, RigidBodyAttitude, System, planar_localization
from liemef.systems._file import load_system_file
from localization_scenario import circle_samples
from refusals import raises as _raises


# --- log files ------------------------------------------------------------------------------------------------
def _good_npz(path):
    ts = 0.1 * np.arange(20)
    np.savez(path, ts=ts, us=np.zeros((20, 3)), ys=np.ones((20, 2)))
    return path


@pytest.fixture
def localization():
    return planar_localization()


LOG_CASES = {
    "zero-byte npz": lambda p: p.write_bytes(b""),
    "truncated npz": lambda p: p.write_bytes(_good_npz(p).read_bytes()[:300]),
    "bit-flipped npz": lambda p: p.write_bytes(_flip(_good_npz(p).read_bytes())),
    "npy renamed npz": lambda p: np.save(open(p, "wb"), np.zeros(3)),
    "text as npz": lambda p: p.write_text("t,v_x\n0,1\n"),
    "pickled npz": lambda p: np.savez(p, ts=np.array([{"a": 1}], dtype=object)),
}


def _flip(data: bytes) -> bytes:
    """The archive with one byte of its first member's data flipped (its CRC no longer matches)."""
    b = bytearray(data)
    b[200] ^= 0xFF
    return bytes(b)


@pytest.mark.parametrize("case", sorted(LOG_CASES))
def test_a_corrupt_npz_log_is_named(case, tmp_path, localization):
    p = tmp_path / "log.npz"
    LOG_CASES[case](p)
    _raises(lambda: io.read_log(p, localization), "log", str(p))


def test_a_complex_npz_log_is_refused(tmp_path, localization):
    p = tmp_path / "log.npz"
    np.savez(p, ts=0.1 * np.arange(5), us=np.zeros((5, 3)) + 1j, ys=np.ones((5, 2)))
    _raises(lambda: io.read_log(p, localization), str(p), "'us'", "complex", "1j")


def test_a_zipped_archive_without_arrays_is_named(tmp_path, localization):
    p = tmp_path / "log.npz"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("readme.txt", "not an array")
    _raises(lambda: io.read_log(p, localization), "log", str(p))


def test_a_csv_with_a_byte_order_mark_is_read(tmp_path, localization):
    p = tmp_path / "log.csv"
    header = ",".join(io.LogLayout.of(localization).header)
    p.write_bytes(("\ufeff" + header + "\n" + "\n".join(f"{0.1 * k},1,0,0,{k},0" for k in range(5)) + "\n")
                  .encode("utf-8"))
    log = io.read_log(p, localization)
    assert log.ts.shape == (5,) and np.all(log.ys[:, 0] == np.arange(5))


def test_a_latin1_csv_names_the_file(tmp_path, localization):
    p = tmp_path / "log.csv"
    header = ",".join(io.LogLayout.of(localization).header)
    p.write_bytes((header + "\n0,1,0,0,0,0\n# caf\xe9\n").encode("latin-1"))
    _raises(lambda: io.read_log(p, localization), str(p), "UTF-8", r"b'\xe9'")


def test_a_binary_csv_names_the_file(tmp_path, localization):
    p = tmp_path / "log.csv"
    p.write_bytes(b"t,v_x\x00\x00\n")
    _raises(lambda: io.read_log(p, localization), str(p))


# --- group elements -------------------------------------------------------------------------------------------
def _se2(c, s):
    return SE2(jnp.array([c, s, 0.0, 0.0]))


OFF_GROUP = {
    "SE(2) (cos, sin) = (3, 0)": (lambda: _se2(3.0, 0.0), 2.0),
    "SE(2) (cos, sin) = (0, 0)": (lambda: _se2(0.0, 0.0), 1.0),
    "zero quaternion": (lambda: SO3(jnp.zeros(4)), 1.0),
    "quaternion of norm 3": (lambda: SO3(jnp.array([3.0, 0.0, 0.0, 0.0])), 2.0),
}


@pytest.fixture(scope="module")
def se2_filter():
    return liemef.MinimumEnergyFilter(planar_localization())


@pytest.fixture(scope="module")
def attitude_filter():
    return liemef.MinimumEnergyFilter(RigidBodyAttitude())


@pytest.mark.parametrize("case", sorted(OFF_GROUP))
def test_an_element_off_the_group_is_refused_by_init_with_its_distance(case, se2_filter, attitude_filter):
    make, distance = OFF_GROUP[case]
    g = make()
    if isinstance(g, SE2):
        flt, g0 = se2_filter, g
    else:
        flt = attitude_filter
        g0 = flt.system.group((g, Rn[3](jnp.zeros(3))))
    _raises(lambda: flt.init(g0, np.eye(flt.n)), "g0", f"{distance:.6g} off the group", str(_validate.ON_GROUP))


@pytest.mark.parametrize("case", sorted(OFF_GROUP))
def test_an_element_off_the_group_is_refused_by_simulate(case):
    make, distance = OFF_GROUP[case]
    g = make()
    if isinstance(g, SE2):
        sysm = PlanarRigidBody()
        g0 = TSE2((g, Rn[3](jnp.zeros(3))))
        fn = lambda t: jnp.zeros(2)  # noqa: E731
    else:
        sysm = RigidBodyAttitude()
        g0 = sysm.group((g, Rn[3](jnp.zeros(3))))
        fn = lambda t: jnp.zeros(3)  # noqa: E731
    _raises(lambda: simulate(sysm, g0, fn, np.arange(3.0), _key()), "g0", f"{distance:.6g} off the group")


def test_an_element_within_the_tolerance_is_accepted(se2_filter):
    g = _se2(1.0 + 0.5 * _validate.ON_GROUP, 0.0)
    assert se2_filter.init(g, np.eye(3)).g_hat is g


def test_terms_refuses_an_element_off_the_group(se2_filter):
    _raises(lambda: se2_filter.terms(_se2(0.0, 0.0), np.eye(3), np.zeros(3), np.zeros(2), dt=0.1), "g_hat",
            "1 off the group")


def _key():
    import jax

    return jax.random.key(0)


# --- physical parameters --------------------------------------------------------------------------------------
PHYSICAL = [
    (PlanarRigidBody, "J", 0), (PlanarRigidBody, "J", float("nan")), (PlanarRigidBody, "m", -1),
    (PlanarRigidBody, "l", 0), (PlanarRigidBody, "l", float("inf")), (PlanarRigidBody, "J", 1j),
    (ChaplyginSleigh, "J", 0), (ChaplyginSleigh, "m", -1), (ChaplyginSleigh, "l", 0),
    (ChaplyginSleigh, "a", float("nan")), (ChaplyginSleigh, "l", float("inf")),
]


@pytest.mark.parametrize(("cls", "name", "value"), PHYSICAL, ids=[f"{c.__name__}-{n}={v}" for c, n, v in PHYSICAL])
def test_a_bad_physical_parameter_is_refused(cls, name, value):
    _raises(lambda: cls(**{name: value}), f"{name}:", value)


@pytest.mark.parametrize(("inertia", "shown"), [(np.zeros((3, 3)), "smallest eigenvalue 0"),
                                                (np.diag([2.0, -5.0, 3.0]), "smallest eigenvalue -5"),
                                                (np.diag([np.nan, 5.0, 3.0]), "nan")])
def test_a_bad_inertia_is_refused(inertia, shown):
    _raises(lambda: RigidBodyAttitude(inertia=inertia), "inertia:", shown)


def test_a_zero_direction_is_refused():
    _raises(lambda: RigidBodyAttitude(a1=(0.0, 0.0, 0.0)), "a1:", "nonzero direction", "[0. 0. 0.]")


def test_a_zero_or_negative_gps_std_is_refused():
    _raises(lambda: planar_localization(gps_std=0.0), "std:", "0.0")
    _raises(lambda: planar_localization(gps_std=-1.0), "std:", "-1.0")


# --- dtypes -----------------------------------------------------------------------------------------------------
def _tiny_system(**kw):
    args = dict(B=np.eye(2), D=np.eye(1), Q=np.eye(1), R=np.eye(2), n_inputs=1)
    args.update(kw)
    dyn = args.pop("dynamics", lambda g, u, t: jnp.array([g.x[1], u[0]]))
    return System(group_type=Rn[2], dynamics_fn=dyn, output_fn=lambda g, t: g.x[:1], **args)


@pytest.fixture(scope="module")
def tiny():
    flt = liemef.MinimumEnergyFilter(_tiny_system())
    return flt, flt.init(Rn[2](jnp.zeros(2)), np.eye(2))


def test_complex_samples_times_gains_and_states_are_refused(tiny):
    flt, state = tiny
    ts, us, ys = np.arange(3.0), np.zeros((3, 1)), np.ones((3, 1))
    _raises(lambda: flt.run(state, ts, us, ys + 1j), "ys", "complex")
    _raises(lambda: flt.run(state, ts, us + 2j, ys), "us", "complex")
    _raises(lambda: flt.run(state, ts + 0.5j, us, ys), "ts", "complex", "0.5j")
    _raises(lambda: flt.init(Rn[2](jnp.zeros(2)), np.eye(2) * (1 + 1j)), "K0", "complex")
    _raises(lambda: flt.step(state, 0.0, np.array([1j]), np.ones(1), 0.1), "u", "complex")
    _raises(lambda: Rn[2](np.array([1.0 + 2j, 0.0])), "complex")
    _raises(lambda: SE2.from_coords(np.array([0.1j, 0.0, 0.0])), "complex")


def test_object_and_string_arrays_are_refused(tiny):
    flt, state = tiny
    ts, us = np.arange(3.0), np.zeros((3, 1))
    _raises(lambda: flt.run(state, ts, us, np.array([[1.0], [None], [2.0]], dtype=object)), "ys", "objects")
    _raises(lambda: flt.run(state, ts, us, np.array([["1"], ["2"], ["3"]])), "ys", "strings")
    _raises(lambda: flt.run(state, [0.0, [1.0, 2.0], 3.0], us, np.ones((3, 1))), "ts")


def test_integers_are_converted(tiny):
    flt, state = tiny
    a = flt.run(state, np.arange(3), np.zeros((3, 1), int), np.ones((3, 1), int), engine="xla")
    b = flt.run(state, np.arange(3.0), np.zeros((3, 1)), np.ones((3, 1)), engine="xla")
    np.testing.assert_array_equal(np.asarray(a.K), np.asarray(b.K))


@pytest.mark.parametrize("name", ["B", "D", "Q", "R"])
def test_a_complex_system_matrix_is_refused(name):
    value = {"B": np.eye(2), "D": np.eye(1), "Q": np.eye(1), "R": np.eye(2)}[name] * (1 + 1j)
    _raises(lambda: _tiny_system(**{name: value}), f"{name}:", "complex")


def test_dynamics_returning_complex_values_are_refused():
    _raises(lambda: _tiny_system(dynamics=lambda g, u, t: jnp.array([g.x[1], u[0]]) * (1 + 1j)), "dynamics",
            "complex")


def test_a_huge_weight_is_checked_without_overflow():
    sysm = _tiny_system(Q=1e308 * np.eye(1))
    assert float(sysm.Q[0, 0]) == 1e308
    _raises(lambda: _tiny_system(Q=-1e308 * np.eye(1)), "Q:", "smallest eigenvalue -1e+308")


# --- integer ranges ---------------------------------------------------------------------------------------------
def test_huge_and_negative_integers_are_refused():
    sysm = PlanarRigidBody()
    g0 = TSE2((SE2.identity(), Rn[3](jnp.zeros(3))))
    fn = lambda t: jnp.zeros(2)  # noqa: E731
    _raises(lambda: simulate(sysm, g0, fn, np.arange(3.0), _key(), substeps=2**70), "substeps", 2**70)
    _raises(lambda: simulate(sysm, g0, fn, np.arange(3.0), _key(), substeps=0), "substeps", "got 0")
    _raises(lambda: simulate(sysm, g0, fn, np.arange(3.0), _key(), substeps=2.5), "substeps", "2.5")
    _raises(lambda: trial_keys(2**70, 3), "seed", 2**70)
    _raises(lambda: trial_keys(-1, 3), "seed", "got -1")
    _raises(lambda: trial_keys(0, 0), "runs", "got 0")
    _raises(lambda: tse2.TSE2Config(seed=2**70), "seed", 2**70)
    _raises(lambda: _tiny_system(n_inputs=-1), "n_inputs", "got -1")
    _raises(lambda: liemef.MinimumEnergyFilter(_tiny_system(), substeps=2**70), "substeps", 2**70)
    _raises(lambda: liemef.MinimumEnergyFilter(_tiny_system(), max_substeps=2**70), "max_substeps", 2**70)


def test_a_huge_integer_as_a_number_is_converted_or_named():
    assert _validate.real("x", 2**70) == float(2**70)
    _raises(lambda: _validate.real("x", 2**1100), "x:", "1101 bits")


# --- terms ------------------------------------------------------------------------------------------------------
def test_terms_refuses_a_nan_interval_time_or_gain(se2_filter):
    """``terms`` takes any finite K (r, A, E, W are polynomials in it; the closed-form tests use random K, and
    K = -I gives the values of those polynomials there), and refuses what is not finite or not real."""
    g = SE2.identity()
    args = (np.zeros(3), np.zeros(2))
    _raises(lambda: se2_filter.terms(g, -np.eye(3), *args, dt=float("nan")), "dt", "nan")
    _raises(lambda: se2_filter.terms(g, np.eye(3), *args, float("nan"), dt=0.1), "t:", "nan")
    _raises(lambda: se2_filter.terms(g, np.diag([1.0, np.nan, 1.0]), *args, dt=0.1), "K:", "nan")
    _raises(lambda: se2_filter.terms(g, np.eye(3) * 1j, *args, dt=0.1), "K:", "complex")
    plus, minus = se2_filter.terms(g, np.eye(3), *args, dt=0.1), se2_filter.terms(g, -np.eye(3), *args, dt=0.1)
    np.testing.assert_allclose(np.asarray(minus.E), np.asarray(plus.E))  # E does not depend on K


# --- system files -----------------------------------------------------------------------------------------------
SYSTEM_FILE = """
import jax.numpy as jnp, numpy as np
from liemef.groups import Rn
from liemef.systems import System
system = System(group_type=Rn[2], dynamics_fn=lambda g, u, t: jnp.array([g.x[1], 0.0]),
                output_fn=lambda g, t: g.x[:1], B=np.eye(2), D=np.eye(1), Q=np.eye(1), R=np.eye(2))
"""


@pytest.mark.parametrize(("body", "shown"), [("raise SystemExit(0)", "SystemExit: 0"),
                                             ("import sys\nsys.exit(3)", "SystemExit: 3"),
                                             ("raise KeyError('gps')", "KeyError: 'gps'"),
                                             ("1 / 0", "ZeroDivisionError"),
                                             ("def f(:\n    pass", "SyntaxError")])
def test_a_system_file_that_raises_or_exits_is_named(body, shown, tmp_path):
    p = tmp_path / "sys.py"
    p.write_text(SYSTEM_FILE + body + "\n")
    _raises(lambda: load_system_file(p), "--system-file", str(p), shown)


@pytest.mark.parametrize(("guess", "shown"), [("raise RuntimeError('no fix')", "RuntimeError: no fix"),
                                              ("raise SystemExit(0)", "SystemExit: 0"),
                                              ("return [1.0]", "expected shape (2,), got (1,)"),
                                              ("return [1j, 0]", "complex"),
                                              ("return [np.nan, 0]", "nan")])
def test_an_initial_guess_that_fails_is_named(guess, shown, tmp_path):
    p = tmp_path / "sys.py"
    p.write_text(SYSTEM_FILE + f"def initial_guess(y0):\n    {guess}\n")
    user = load_system_file(p)
    _raises(lambda: user.guess(np.ones(1)), "initial_guess", str(p), shown)


# --- hostile logs at run time ------------------------------------------------------------------------------------
# A NaN input sample, a 1e4 m GPS outlier with no gate, a 1.5 s gap and a huge K0 (the inertial-navigation trial of
# issue 19 on SE(2), which compiles in seconds): each ends in a finite estimate with its warnings, or in a failure
# value that says where, when and why; never in NaN estimates written as a success, never in a traceback.
def _hostile_log(path, outlier=True, N=600):
    """A circle at 0.785 m/s, 100 Hz odometry with input sample 150 NaN, GPS at 2 Hz (std 0.3 m) with fix 200 at
    (1e4, 1e4) m if ``outlier``, and no samples in [3, 4.5) s. Returns the times kept and the true positions."""
    ts, p, _, us, ys = circle_samples(N, slice(None, None, 50), 0.3)
    us[150] = np.nan
    if outlier:
        ys[200] = [1e4, 1e4]
    keep = (ts < 3) | (ts >= 4.5)
    io.write_log(path, planar_localization(), ts[keep], us[keep], ys[keep])
    return ts[keep], p[keep]


def _filter(path, updates="discrete", **kw):
    from liemef.studies import logs

    return logs.filter_log("localization", path, x0=np.zeros(3), updates=updates, **kw)


def test_a_nan_input_and_a_gap_are_filtered_through_and_said(tmp_path):
    ts, p = _hostile_log(tmp_path / "log.csv", outlier=False)
    run = _filter(tmp_path / "log.csv", K0=1.0)
    assert run.ok and run.report["gaps"] == 1 and run.report["inputs_held"] == 1
    said = " | ".join(run.warnings())
    assert "longest 1.51 s) were predicted through" in said and "1 input sample(s) were missing" in said
    assert "beyond the chi-square" not in said
    coords = np.asarray(run.trajectory.coords())
    assert np.isfinite(coords).all() and np.max(np.linalg.norm(coords[:, 1:] - p, axis=1)) < 1.0
    assert run.metrics["innovation"]["outliers"]["gps"]["count"] == 0


def test_an_outlier_the_filter_used_is_reported(tmp_path):
    """With no gate the 1e4 m fix is used (the estimate jumps: a finite, honest result of the model) and the run
    says so, with the fix's time and size, and how to reject such fixes."""
    _hostile_log(tmp_path / "log.csv")
    run = _filter(tmp_path / "log.csv", K0=1.0)
    assert run.ok
    out = run.metrics["innovation"]["outliers"]["gps"]
    assert out["largest_t"] == 2.0 and out["largest_sigmas"] > 1e3 and out["count"] >= 1
    assert any(w.startswith(f"gps: {out['count']} sample(s) lay beyond the chi-square 0.999999 bound") and
               "at t = 2 s" in w and "gate" in w for w in run.warnings())


def test_an_interval_forced_past_the_sub_step_cap_is_said(tmp_path):
    """Held over its interval (updates="hold"), the 1e4 m fix makes the interval so stiff that its integration hits
    the sub-step cap: the run stays ok (the count is in the report), and its warnings say the estimate after such
    an interval may be far off, and how to avoid it; the discrete update of the test above hits no cap and says
    nothing of it. From K0 = I the held run fails at such an interval: its warning says the run failed, never that
    it is ok."""
    _hostile_log(tmp_path / "log.csv")
    held = _filter(tmp_path / "log.csv", updates="hold", K0=0.1)
    assert held.ok and held.report["substeps_capped"] >= 1
    said = [w for w in held.warnings() if "sub-step cap" in w]
    assert len(said) == 1 and said[0].startswith(f"{held.report['substeps_capped']} interval(s) hit the sub-step "
                                                 "cap (256 steps)") and "--updates discrete" in said[0]
    assert "may be far off though the run is ok" in said[0]
    failed = _filter(tmp_path / "log.csv", updates="hold", K0=1.0)
    assert not failed.ok and failed.report["substeps_capped"] >= 1
    said = [w for w in failed.warnings() if "sub-step cap" in w]
    assert len(said) == 1 and "and the run failed" in said[0] and "run is ok" not in said[0]
    discrete = _filter(tmp_path / "log.csv", K0=1.0)
    assert discrete.report["substeps_capped"] == 0 and not any("sub-step cap" in w for w in discrete.warnings())


def test_a_huge_k0_fails_as_a_value_that_says_why(tmp_path):
    """K0 = 1e12 I: K's condition number passes 1e12 and the first fix after t = 0 breaks its positive
    definiteness. `liemef run` exits 1, without a traceback, with failure.json alone, naming the interval, its
    time, the cause, K's conditioning and the fix's innovation."""
    from click.testing import CliRunner

    from liemef.cli import cli

    _hostile_log(tmp_path / "log.csv")
    res = CliRunner().invoke(cli, ["run", "--system", "localization", "--log", str(tmp_path / "log.csv"), "--out",
                                   str(tmp_path / "o"), "--x0", "0,0,0", "--k0", "1e12", "--updates", "discrete",
                                   "--no-progress"])
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit) and "Traceback" not in res.output, res.output
    assert res.output.startswith("Failed to filter ") and "Filtered" not in res.output
    assert "filter failed over the sample interval 50 ([0.5, 0.51] s): the gain K lost positive definiteness" in \
        res.output and "condition number of" in res.output and "gps 0." in res.output
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["failure.json"]
    failure = io.read_json(tmp_path / "o" / "failure.json")
    assert failure["interval"]["K_condition"] > 1e12 and failure["interval"]["gap"] is False
    assert failure["interval"]["samples"]["gps"]["components"] == ["gps_x", "gps_y"]
    assert all(np.isfinite(list(failure["last_good_state"]["coords"].values())))


# --- issue 32: groups ---
groups = liemef.groups
SO3_BASIS = groups.MatrixGroup.from_basis("SO3Basis", np.asarray(SO3.hat(jnp.eye(3))))
"""A user's MatrixGroup without a rule: membership is the exp/log round trip."""
EVERY_GROUP = [groups.SO2, SO3, SE2, groups.SE3, groups.SE23, groups.SEK3[3], groups.R3, groups.SL3, groups.Sim3, TSE2,
               groups.TSO3, groups.SE2R2, groups.SO2R1, SO3_BASIS]
_ids = [G.__name__ for G in EVERY_GROUP]
ORTHOGONALITY = "orthogonality max|R^T R - I|"
DETERMINANT = "determinant |det R - 1|"


def _defect(G, case):
    """The (defect, size) that ``G.from_matrix`` names for the matrix of ``case`` (:func:`_bent`); None when
    that matrix is an element of G."""
    if issubclass(G, groups.Product):  # the first factor's block holds the change
        inner = _defect(G.factor_types[0], case)
        f = G.factor_types[0]
        return (f"factor 0 ({f.__name__}) block M[0:{f.matrix_dim}, 0:{f.matrix_dim}]: {inner[0]}", inner[1])
    if G is SO3_BASIS:
        return ("round trip |exp(log M) - M|_1 / (1 + |M|_1)", None)
    if G is groups.SL3:
        return {"shear": None, "2I": ("determinant |det M - 1|", 7.0), "flip": ("determinant |det M - 1|", 2.0)}[case]
    if issubclass(G, Rn):
        return ("identity block max|M[:3, :3] - I|", {"shear": 0.1, "2I": 1.0, "flip": 2.0}[case])
    if G is groups.Sim3:
        of = " of R = A / |det A|^(1/3)"
        return {"shear": (ORTHOGONALITY + of, 0.1), "2I": ("bottom row max|M[3] - [0, 1]|", 1.0),
                "flip": (DETERMINANT + of, 2.0)}[case]
    return {"shear": (ORTHOGONALITY, 0.1), "2I": (ORTHOGONALITY, 3.0), "flip": (DETERMINANT, 2.0)}[case]


def _bent(G, case):
    """The identity matrix of G sheared (M[0, 1] = 0.1), doubled, or with M[1, 1] = -1 (a reflection)."""
    M = np.eye(G.matrix_dim)
    if case == "shear":
        M[0, 1] = 0.1
    elif case == "2I":
        M = 2.0 * M
    else:
        M[1, 1] = -1.0
    return M


@pytest.mark.parametrize("case", ["shear", "2I", "flip"])
@pytest.mark.parametrize("G", EVERY_GROUP, ids=_ids)
def test_from_matrix_refuses_a_matrix_off_the_group_naming_the_defect(G, case):
    """A shear, 2 I and a reflection: refused by every group's from_matrix, naming M, the defect and its size
    (a shear is an element of SL(3), and is taken)."""
    M, want = _bent(G, case), _defect(G, case)
    if want is None:
        np.testing.assert_array_equal(G.from_matrix(M).as_matrix(), M)
        return
    defect, size = want
    words = ["M: expected a matrix of", G.__name__, str(_validate.ON_GROUP), f"got {defect} = "]
    _raises(lambda: G.from_matrix(M), *words, *([] if size is None else [f"= {size:.6g}"]))


@pytest.mark.parametrize("G", EVERY_GROUP, ids=_ids)
def test_from_matrix_refuses_nan(G):
    M = np.eye(G.matrix_dim)
    M[0, 0] = np.nan
    _raises(lambda: G.from_matrix(M), "M: expected finite values, got nan at index (0, 0)")


@pytest.mark.parametrize("G", EVERY_GROUP, ids=_ids)
def test_from_matrix_takes_a_matrix_within_the_tolerance(G):
    """An element's matrix bent by 0.4 ON_GROUP is taken: a MatrixGroup stores it as it is, a closed form keeps
    its parameters (a quaternion, (cos, sin)) within ON_GROUP of it."""
    rng = np.random.default_rng(3)
    M = np.array(G.exp(0.3 * rng.standard_normal(G.tangent_dim)).as_matrix())
    M[0, 1] += 0.4 * _validate.ON_GROUP
    atol = 0.0 if issubclass(G, groups.MatrixGroup) else _validate.ON_GROUP
    np.testing.assert_allclose(G.from_matrix(M).as_matrix(), M, rtol=0, atol=atol)


@pytest.mark.parametrize("G", [G for G in EVERY_GROUP if issubclass(G, (SE2, groups.SEK3, Rn, groups.Product))
                               or G is groups.Sim3], ids=lambda G: G.__name__)
def test_from_matrix_refuses_a_bottom_row_or_a_block_off_the_diagonal(G):
    """The last row of a homogeneous matrix must be (0, ..., 0, 1); a product's matrix is block diagonal."""
    M = np.eye(G.matrix_dim)
    M[-1, 0] = 0.3
    defect = "off-diagonal blocks max|M|" if issubclass(G, groups.Product) else "bottom row"
    _raises(lambda: G.from_matrix(M), "M: expected a matrix of", G.__name__, defect, "= 0.3")


def test_from_matrix_names_the_batch_index():
    M = np.stack([np.eye(4), np.diag([1.0, 1.0, 1.0, 2.0])])
    _raises(lambda: groups.SE3.from_matrix(M), "bottom row max|M[3] - [0, 1]| = 1 at batch index (1,)")


def _with_params(g, make):
    """``g`` with its first parameter array replaced by ``make(array)``."""
    import jax

    leaves, tree = jax.tree_util.tree_flatten(g)
    return jax.tree_util.tree_unflatten(tree, [jnp.asarray(make(np.array(leaves[0])))] + leaves[1:])


def _unit_size(G):
    """How many leading parameters of G's (first factor's) first array form its unit vector: (cos, sin) or the
    quaternion; 0 for a MatrixGroup or R^n."""
    base = G.factor_types[0] if issubclass(G, groups.Product) else G
    return 2 if issubclass(base, (groups.SO2, SE2)) else 4 if issubclass(base, (SO3, groups.SEK3)) else 0


def _off_group_state(G, case):
    """``(element, defect, size)``: G's identity with NaN parameters, or with its unit vector scaled to norm 0,
    1.008 or 2 (a MatrixGroup: its matrix 2 I); size None when the message need not show it."""
    e = G.identity()
    if case == "NaN":
        return _with_params(e, lambda p: np.full_like(p, np.nan)), "expected finite values, got nan", None
    if issubclass(G, groups.MatrixGroup):
        return (_with_params(e, lambda p: 2.0 * p), *_defect(G, "2I"))
    k = _unit_size(G)
    what = "norm | |(cos, sin)| - 1 |" if k == 2 else "quaternion norm | |q| - 1 |"
    if issubclass(G, groups.Product):
        what = f"factor 0 ({G.factor_types[0].__name__}): {what}"
    scale = {"|v| = 0": 0.0, "|v| = 1.008": 1.008, "|v| = 2": 2.0}[case]
    return _with_params(e, lambda p: np.concatenate([scale * p[:k], p[k:]])), what, abs(scale - 1.0)


STATE_CASES = [(G, "NaN") for G in EVERY_GROUP] + \
    [(G, "2I") for G in EVERY_GROUP if issubclass(G, groups.MatrixGroup)] + \
    [(G, c) for G in EVERY_GROUP if _unit_size(G) for c in ("|v| = 0", "|v| = 1.008", "|v| = 2")]


def _any_system(G):
    n = G.tangent_dim
    # an output defined at every element the init takes (log may not be, a hair off a matrix group)
    return System(group_type=G, dynamics_fn=lambda g, u, t: jnp.zeros(n),
                  output_fn=lambda g, t: g.as_matrix().reshape(-1)[:1],
                  B=np.eye(n), D=np.eye(1), Q=np.eye(1), R=np.eye(n))


def _filters(system):
    from liemef.filters import baselines

    return [liemef.MinimumEnergyFilter(system), baselines.invariant_ekf(system), baselines.local_ekf(system),
            baselines.ukf_m(system)]


@pytest.mark.parametrize(("G", "case"), STATE_CASES, ids=[f"{G.__name__}-{c}" for G, c in STATE_CASES])
def test_every_filter_init_refuses_a_state_off_the_group_naming_the_defect(G, case):
    """NaN parameters, a zero quaternion (or (cos, sin)), |q| = 1.008 and 2, a MatrixGroup's 2 I: refused by the
    init of the minimum-energy filter, the EKFs and the UKF-M, naming g0, the defect and its size."""
    g, defect, size = _off_group_state(G, case)
    for flt in _filters(_any_system(G)):
        words = ["g0:", defect] + ([] if size is None else [f"got one {size:.6g} off the group by its"])
        _raises(lambda flt=flt: flt.init(g, np.eye(G.tangent_dim)), *words)


@pytest.mark.parametrize("G", EVERY_GROUP, ids=_ids)
def test_every_filter_init_takes_a_state_within_the_tolerance(G):
    """Its unit vector scaled by 1 + ON_GROUP / 2, or a MatrixGroup's matrix bent by 0.4 ON_GROUP: taken as it is."""
    k = _unit_size(G)
    bend = (lambda p: np.concatenate([(1.0 + 0.5 * _validate.ON_GROUP) * p[:k], p[k:]])) if k else \
        (lambda p: p + 0.4 * _validate.ON_GROUP * (np.arange(p.size) == 1))
    g = _with_params(G.exp(0.2 * np.ones(G.tangent_dim)), bend)
    for flt in _filters(_any_system(G)):
        assert flt.init(g, np.eye(G.tangent_dim)).g_hat is g


@pytest.mark.parametrize("G", [G for G in EVERY_GROUP if issubclass(G, groups.MatrixGroup)],
                         ids=lambda G: G.__name__)
def test_a_matrix_group_element_the_init_takes_has_a_logarithm(G):
    """A MatrixGroup matrix bent by 0.4 ON_GROUP (taken by every init) has a finite logarithm within 1e-6 of the
    unbent one's: an output or a coordinate of it is no NaN."""
    g = G.exp(0.2 * np.ones(G.tangent_dim))
    bent = _with_params(g, lambda p: p + 0.4 * _validate.ON_GROUP * (np.arange(p.size) == 1))
    np.testing.assert_allclose(np.asarray(bent.log()), np.asarray(g.log()), rtol=0, atol=1e-6)


def test_madgwick_init_refuses_a_quaternion_off_unit():
    from liemef.filters.baselines import Madgwick
    from liemef.systems import attitude_imu

    flt = Madgwick(attitude_imu())
    g, defect, size = _off_group_state(flt.system.group, "|v| = 1.008")
    _raises(lambda: flt.init(g), "g0:", defect, "got one 0.008 off the group")


@pytest.mark.parametrize("scale", [1.008, 2.0, 0.0])
def test_pose3d_init_refuses_a_quaternion_off_unit(scale):
    """Issue 32: MinimumEnergyFilter(pose3d()).init took |q| = 1.008, 2 and 0 (the last ran 'ok' with NaN
    coordinates for a whole log)."""
    from liemef.systems import pose3d

    flt = liemef.MinimumEnergyFilter(pose3d())
    g = groups.SE3(jnp.array([scale, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0]))
    _raises(lambda: flt.init(g, np.eye(6)), "g0:", "quaternion norm", f"got one {abs(scale - 1.0):.6g} off")


def test_inertial_navigation_refuses_a_sheared_extended_pose():
    """Issue 32: a sheared SE_2(3) matrix is refused by SE23.from_matrix, and the quaternion Shepperd's method
    makes of it (|q| = 1.008) by inertial navigation's init."""
    from liemef.groups._so3 import quaternion_of_matrix
    from liemef.systems import inertial_navigation

    M = np.eye(5)
    M[:3, :3] = R = [[1.0, 0.3, 0.3], [0.0, 1.0, 0.3], [0.0, 0.0, 1.0]]
    _raises(lambda: groups.SE23.from_matrix(M), "M: expected a matrix of SE23",
            f"orthogonality max|R^T R - I| = {np.abs(np.transpose(R) @ R - np.eye(3)).max():.6g}")
    q = np.asarray(quaternion_of_matrix(jnp.asarray(R)))
    assert round(float(np.linalg.norm(q)), 3) == 1.008
    g = groups.SE23(jnp.concatenate([q, jnp.zeros(6)]))
    flt = liemef.MinimumEnergyFilter(inertial_navigation())
    _raises(lambda: flt.init(g, np.eye(9)), "g0: expected an element of SE23", "quaternion norm",
            f"got one {abs(np.linalg.norm(q) - 1.0):.6g} off the group")


def test_a_matrix_group_rule_is_used_and_checked():
    """A user's rule (from_basis(rule=...)) decides membership for from_matrix and init; a rule that is not a
    function is refused by name."""
    def rule(M):
        return {"orthogonality": float(np.abs(M.T @ M - np.eye(3)).max()), "det": abs(np.linalg.det(M) - 1.0)}

    G = groups.MatrixGroup.from_basis("SO3Ruled", np.asarray(SO3.hat(jnp.eye(3))), rule=rule)
    _raises(lambda: G.from_matrix(np.diag([1.0, 1.0, -1.0])), "M: expected a matrix of SO3Ruled", "got det = 2")
    flat = G(jnp.asarray(_bent(G, "shear").ravel()))
    _raises(lambda: liemef.MinimumEnergyFilter(_any_system(G)).init(flat, np.eye(3)), "g0:",
            "got one 0.1 off the group by its orthogonality")
    _raises(lambda: groups.MatrixGroup.from_basis("Bad", np.asarray(SO3.hat(jnp.eye(3))), rule=3), "rule:", "int")


def _nan_after(t0):
    return lambda t: jnp.where(t > t0, jnp.nan, 1.0) * jnp.ones(2)


@pytest.mark.parametrize(("fn", "substeps", "first"), [
    (_nan_after(0.25), 1, "t = 0.30000000000000004"),  # the sample times only
    (_nan_after(0.25), 4, "t = 0.275"),  # a truth step's start between samples
    (lambda t: jnp.array([1.0, jnp.log(t - 0.35)]), 1, "t = 0.0"),
    (lambda t: jnp.array([1.0 / (t - 0.5), 0.0]), 1, "t = 0.5"),  # inf, not NaN
], ids=["nan-after-0.25", "nan-after-0.25-substeps", "log-of-negative", "inf-at-0.5"])
def test_simulate_refuses_an_input_function_that_returns_non_finite_values(fn, substeps, first):
    """Issue 32: simulate returned a NaN log for such a function. It names input_fn and the first time it
    returned non-finite values, with those values."""
    _raises(lambda: simulate(PlanarRigidBody(), TSE2.identity(), fn, np.arange(0.0, 1.0, 0.1), _key(),
                             substeps=substeps), "input_fn: expected finite inputs u(t)", first,
            "the first time it returned non-finite values")


def _pose3d_log(path):
    header = "t,omega_x,omega_y,omega_z,v_x,v_y,v_z,position_x,position_y,position_z"
    rows = [f"{0.1 * k:.1f},0,0,0.1,1,0,0,{0.1 * k:.1f},0,0" for k in range(20)]
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


@pytest.mark.parametrize("x0", [[np.nan, 0, 0, 0, 0, 0], [1e300, 0, 0, 0, 0, 0]], ids=["nan", "overflow"])
def test_filter_log_refuses_an_x0_that_gives_no_element(tmp_path, x0):
    """Coordinates whose exp is not finite (NaN, a rotation vector of 1e300 rad) are refused by name, not
    handed to init as a NaN g0."""
    from liemef.studies import logs

    _raises(lambda: logs.filter_log("pose3d", _pose3d_log(tmp_path / "log.csv"), x0=x0),
            "x0: expected the coordinates of an element of SE3", "from_coords(x0): expected finite values")


def test_cli_run_refuses_an_x0_off_the_group(tmp_path):
    """`liemef run --x0` with coordinates of no element: exit 2 naming --x0 and the group, nothing written."""
    from click.testing import CliRunner

    from liemef.cli import cli

    res = CliRunner().invoke(cli, ["run", "--system", "pose3d", "--log", str(_pose3d_log(tmp_path / "log.csv")),
                                   "--out", str(tmp_path / "o"), "--x0", "1e300,0,0,0,0,0", "--no-progress"])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    assert "Invalid value for '--x0': expected the coordinates of an element of SE3, got [1e+300" in res.output
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


# --- issue 32: the campaign's cluster and the kernel cache -----------------------------------------------------
# The local cluster of `liemef campaign run` admits only its owner: TLS with credentials made for the run, every
# server on 127.0.0.1, no dashboard and HTTP servers that serve nothing; a client without the run's credentials,
# from this process or another, is refused before it can run code. A tls:// scheduler without credentials is a
# named error. A cached kernel library damaged with its manifest rewritten to match is named in an EngineWarning
# and rebuilt, never mapped (a library cut short used to kill the process with SIGBUS); a system whose libraries
# the cache cannot check is refused by name.
INTRUDER = """
import os, sys
from dask.distributed import Client, Security
how, address = sys.argv[1], sys.argv[2]
kw = {"security": Security.temporary()} if how == "its own credentials" else {}
client = Client(address.replace("tls://", "tcp://") if how == "plain tcp" else address, timeout="3s", **kw)
print("RAN CODE IN", client.run(os.getpid), flush=True)
"""


@pytest.fixture(scope="module")
def campaign_cluster():
    """The cluster `liemef campaign run` starts (two workers), its client, the ports this process listened on
    before it, and the workers' pids."""
    import os

    import psutil

    from liemef.studies.campaign._run import _client

    before = {c.laddr for c in psutil.Process().net_connections("inet") if c.status == psutil.CONN_LISTEN}
    client, cluster = _client(None, 2)
    try:
        yield client, cluster, before, client.run(os.getpid)
    finally:
        client.close()
        cluster.close()


def _tls_handshake(port: int, cert: tuple | None = None) -> str:
    """A TLS connection to ``port`` that checks nothing and presents ``cert`` (files (cert, key)) or none, then
    sends 8 bytes: how the server cut it (an SSL or connection error; ``"closed"``), or the first byte it sent."""
    import socket
    import ssl

    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    if cert is not None:
        ctx.load_cert_chain(*cert)
    with socket.create_connection(("127.0.0.1", port), timeout=10) as raw:
        try:
            with ctx.wrap_socket(raw) as tls:
                tls.sendall(b"\0" * 8)
                first = tls.recv(1)
                return f"sent {first!r}" if first else "closed"
        except (ssl.SSLError, ConnectionError) as err:
            return f"{type(err).__name__}: {err}"


def _port(address: str) -> int:
    return int(address.rsplit(":", 1)[1])


@pytest.mark.parametrize("how", ["no credentials", "its own credentials", "plain tcp"])
def test_a_client_without_the_runs_credentials_cannot_run_code_in_the_campaigns_cluster(how, campaign_cluster):
    """Another process connects to the scheduler as a Dask client and asks every worker to run code: refused."""
    import subprocess
    import sys

    _, cluster, _, _ = campaign_cluster
    res = subprocess.run([sys.executable, "-c", INTRUDER, how, cluster.scheduler_address], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 1 and "RAN CODE IN" not in res.stdout, (res.stdout, res.stderr[-2000:])
    last = res.stderr.strip().splitlines()[-1]
    assert {"no credentials": "TypeError: TLS expects a `ssl_context`",
            "its own credentials": "FatalCommClosedError: TLS certificate does not match",
            "plain tcp": "Connection reset by peer"}[how] in last, last


def test_every_server_of_the_campaigns_cluster_refuses_a_stranger(campaign_cluster, tmp_path):
    """Each of its servers (scheduler, workers, nannies) listens on 127.0.0.1 and refuses a TLS client without a
    certificate, or with one the run did not make; its HTTP servers serve nothing, dashboard included."""
    import urllib.error
    import urllib.request

    import psutil
    from dask.distributed import Security

    client, cluster, before, pids = campaign_cluster
    assert cluster.scheduler_address.startswith("tls://127.0.0.1:")
    comm = [_port(cluster.scheduler_address), *map(_port, pids), *(_port(n.address) for n in cluster.workers.values())]
    stranger = Security.temporary()
    (tmp_path / "c.pem").write_text(stranger.tls_client_cert)
    (tmp_path / "k.pem").write_text(stranger.tls_client_key)
    for port in comm:
        for cert in (None, (str(tmp_path / "c.pem"), str(tmp_path / "k.pem"))):
            said = _tls_handshake(port, cert)
            assert said.startswith(("SSL", "Connection", "closed")), (port, cert, said)
    listening = [c.laddr for c in psutil.Process().net_connections("inet")
                 if c.status == psutil.CONN_LISTEN and c.laddr not in before]
    listening += [c.laddr for pid in pids.values() for c in psutil.Process(pid).net_connections("inet")
                  if c.status == psutil.CONN_LISTEN]
    assert {a.ip for a in listening} == {"127.0.0.1"} and set(comm) <= {a.port for a in listening}
    answers = []
    for addr in listening:
        for path in ("/status", "/info/main/workers.html", "/json/identity.json", "/metrics", "/health"):
            try:
                answers.append(urllib.request.urlopen(f"http://127.0.0.1:{addr.port}{path}", timeout=10).status)
            except urllib.error.HTTPError as err:
                answers.append(err.code)
            except (OSError, ValueError):  # a TLS server: the plain request is cut
                answers.append(None)
    assert 200 not in answers and 404 in answers, answers


def test_the_runs_credentials_connect(campaign_cluster):
    import os

    from dask.distributed import Client

    client, cluster, _, pids = campaign_cluster
    with Client(cluster.scheduler_address, security=cluster.security, timeout="20s") as owner:
        assert owner.run(os.getpid) == pids


def test_a_tls_scheduler_without_credentials_is_named_and_with_them_used(campaign_cluster, tmp_path):
    """--scheduler tls://...: without credentials a CampaignError says how to give them; with the cluster's
    credentials in Dask's configuration (distributed.comm.tls.*, as files) the client connects."""
    import gc
    import os

    import dask
    from dask.distributed import Client

    from liemef.studies.campaign import CampaignError
    from liemef.studies.campaign._run import _client

    _, cluster, _, pids = campaign_cluster
    address = cluster.scheduler_address
    before = {id(c) for c in gc.get_objects() if isinstance(c, Client)}
    with pytest.raises(CampaignError) as err:
        _client(address, 1)
    for words in (f"scheduler: cannot connect to {address!r}", "TypeError", "distributed.comm.tls"):
        assert words in str(err.value), str(err.value)
    # the half-made client is finalized at once, not left in a cycle for a later garbage collection (which, run
    # inside another client's start, would wait forever on Dask's loop-runner lock)
    assert err.value.__context__ is None and err.value.__cause__ is None
    assert not [c for c in gc.get_objects() if isinstance(c, Client) and id(c) not in before], "a client lives"
    files = {}
    for key, text in (("ca-file", cluster.security.tls_ca_file), ("client.cert", cluster.security.tls_client_cert),
                      ("client.key", cluster.security.tls_client_key)):
        files[f"distributed.comm.tls.{key}"] = str(tmp_path / key)
        (tmp_path / key).write_text(text)
    with dask.config.set(files):
        client, none = _client(address, 1)
    try:
        assert none is None and client.run(os.getpid) == pids
    finally:
        client.close()


def test_the_cli_names_a_tls_scheduler_it_cannot_use(campaign_cluster, tmp_path):
    from click.testing import CliRunner

    from liemef.cli import cli
    from test_campaign import toml_text

    (tmp_path / "c.toml").write_text(toml_text(tmp_path / "out"))
    address = campaign_cluster[1].scheduler_address
    res = CliRunner().invoke(cli, ["campaign", "run", str(tmp_path / "c.toml"), "--scheduler", address,
                                   "--no-progress"])
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    assert f"scheduler: cannot connect to {address!r}" in res.output and "Traceback" not in res.output


def _small_library(root) -> bytes:
    """A small genuine shared library (one function), as the C compiler makes it."""
    import subprocess

    from liemef import codegen

    if codegen.compiler() is None:
        pytest.skip("no C compiler ($CC, cc, gcc or clang)")
    (root / "small.c").write_text("int small(int x) { return x + 1; }\n")
    subprocess.run([codegen.compiler(), "-shared", "-fPIC", "-o", str(root / "small.so"), str(root / "small.c")],
                   check=True)
    return (root / "small.so").read_bytes()


def _patched(data: bytes, how: str) -> bytes:
    """``data`` (a genuine 64-bit little-endian ELF library) damaged as ``how`` says."""
    import struct

    b = bytearray(data)
    phoff, phnum = struct.unpack_from("<Q", b, 32)[0], struct.unpack_from("<H", b, 56)[0]
    phdrs = [(phoff + 56 * i, struct.unpack_from("<I", b, phoff + 56 * i)[0]) for i in range(phnum)]
    if how == "cut to 4 KiB":
        return bytes(b[:4096])
    if how == "cut by its last byte":
        return bytes(b[:-1])
    if how == "another machine's":
        struct.pack_into("<H", b, 18, 183 if struct.unpack_from("<H", b, 18)[0] != 183 else 62)
    elif how == "an executable":
        struct.pack_into("<H", b, 16, 2)
    elif how == "32-bit":
        b[4] = 1
    elif how == "big-endian":
        b[5] = 2
    elif how == "a segment past the end":  # the last PT_LOAD's file and memory sizes made the file's size
        at = [at for at, kind in phdrs if kind == 1][-1]
        struct.pack_into("<QQ", b, at + 32, len(b), len(b))
    elif how == "no dynamic segment":
        struct.pack_into("<I", b, next(at for at, kind in phdrs if kind == 2), 0)
    elif how == "a string table outside":
        at = next(at for at, kind in phdrs if kind == 2)
        offset, size = struct.unpack_from("<Q", b, at + 8)[0], struct.unpack_from("<Q", b, at + 32)[0]
        entry = next(e for e in range(offset, offset + size, 16) if struct.unpack_from("<q", b, e)[0] == 5)
        struct.pack_into("<Q", b, entry + 8, 1 << 40)
    elif how == "not an ELF file":
        b[:4] = b"MZ\x90\x00"
    return bytes(b)


DAMAGE = {"cut to 4 KiB": r"segment 1 \(PT_LOAD\) ends at byte \d+, past the end of the file \(4096 bytes\)",
          "cut by its last byte": r"its section header table \(bytes \d+ to \d+\) ends past the end of the file",
          "another machine's": r"built for (AArch64 \(e_machine 183\)|x86-64 \(e_machine 62\)), not for this machine",
          "an executable": r"not a shared library \(e_type 2, expected ET_DYN = 3\)",
          "32-bit": r"not a 64-bit ELF file \(EI_CLASS 1\)",
          "big-endian": r"not a little-endian ELF file \(EI_DATA 2\)",
          "a segment past the end": r"segment \d+ \(PT_LOAD\) ends at byte \d+, past the end of the file",
          "no dynamic segment": r"0 dynamic segments \(PT_DYNAMIC\), expected 1",
          "a string table outside": r"its dynamic section's DT_STRTAB \(address 0x10000000000, \d+ bytes\) lies "
                                    r"outside the file part",
          "not an ELF file": r"not an ELF file \(it starts with b'MZ\\x90\\x00'"}


@pytest.mark.parametrize("how", sorted(DAMAGE))
def test_a_damaged_library_with_a_matching_manifest_is_named_and_never_loaded(how, tmp_path):
    """Damaged as the user's own files can be (the manifest rewritten to match): read_verified names the file
    and the defect in an EngineWarning and gives None (the caller rebuilds); load refuses the bytes before they
    are written or mapped."""
    from liemef.codegen import _cache, _elf
    from liemef.engines import EngineWarning

    data = _small_library(tmp_path)
    assert _elf.defect(data) is None
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    lib = _cache.install(cache / "kernel_x.so", _patched(data, how), "k", "kernel", {})
    with pytest.warns(EngineWarning, match=rf"the cached library {re.escape(str(lib.path))} matches its manifest "
                                           rf"but cannot be loaded: {DAMAGE[how]}.*It is rebuilt"):
        assert _cache.read_verified(lib.path, "k", "kernel") is None
    with pytest.raises(RuntimeError, match=rf"{re.escape(str(lib.path))}: not loaded: {DAMAGE[how]}"):
        _cache.load(lib)
    assert sorted(p.name for p in cache.iterdir()) == ["kernel_x.json", "kernel_x.so"]  # no private copy made


def test_a_cut_kernel_cache_warns_and_rebuilds_in_liemef_run(tmp_path, monkeypatch):
    """The issue's case through the CLI: every cached library of `liemef run`'s filter cut to 4 KiB and its
    manifest rewritten to match. The next `liemef run` (a process of its own: a SIGBUS kills it, not pytest)
    exits 0 with the same estimate, an EngineWarning naming each library and its defect, and rebuilds the quick
    one; the -O2 one, which a run this short does not pay for, is rebuilt by the next process that does."""
    import hashlib
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    from liemef.codegen import _cache, _kernel

    _small_library(tmp_path)  # skips without a compiler
    cache = tmp_path / "cache"
    monkeypatch.setenv("LIEMEF_CACHE_DIR", str(cache))
    monkeypatch.setenv("LIEMEF_ENGINE", "c")
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    _hostile_log(tmp_path / "log.csv", outlier=False)
    want = _filter(tmp_path / "log.csv")  # the kernels of `liemef run`'s filter, built here
    for kern in _kernel._KERNELS.values():
        kern.wait()
    libs = sorted(cache.glob("*.so"))
    assert [p.name.split("_")[0] for p in libs] == ["kernel", "quick"]
    genuine = {p: p.read_bytes() for p in libs}
    for lib in libs:
        data = lib.read_bytes()[:4096]
        lib.write_bytes(data)
        man = json.loads(_cache.manifest_path(lib).read_text())
        man.update(size=len(data), sha256=hashlib.sha256(data).hexdigest())
        _cache.manifest_path(lib).write_text(json.dumps(man))
    env = dict(os.environ, LIEMEF_CACHE_DIR=str(cache), LIEMEF_ENGINE="c",
               PYTHONPATH=os.pathsep.join([str(Path(liemef.__file__).resolve().parents[1]),
                                           *[p for p in [os.environ.get("PYTHONPATH")] if p]]))
    res = subprocess.run([sys.executable, "-m", "liemef", "run", "--system", "localization", "--log",
                          str(tmp_path / "log.csv"), "--out", str(tmp_path / "o"), "--x0", "0,0,0", "--updates",
                          "discrete", "--no-progress"], capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, (res.returncode, res.stderr[-3000:])
    for lib in libs:
        assert re.search(rf"EngineWarning: the cached library {re.escape(str(lib))} matches its manifest but cannot "
                         r"be loaded: segment \d+ \(PT_LOAD\) ends at byte \d+, past the end of the file \(4096 "
                         r"bytes\)\. It is rebuilt", res.stderr), res.stderr[-3000:]
    # the quick build, rebuilt byte for byte; a run this short does not pay for the -O2 one
    # (_kernel.OPTIMIZE_AFTER_S): it stays refused on disk until a process that does rebuilds it
    quick, optimized = libs[1], libs[0]
    assert quick.read_bytes() == genuine[quick]
    assert optimized.stat().st_size == 4096
    got = np.load(tmp_path / "o" / "arrays.npz")["filtered"]  # the estimate, by the rebuilt kernel
    np.testing.assert_array_equal(got, np.asarray(want.trajectory.coords()))  # C's quick and -O2: bit for bit
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    with pytest.warns(_cache.EngineWarning, match="matches its manifest but cannot be loaded"):
        again = _filter(tmp_path / "log.csv")
    for kern in _kernel._KERNELS.values():
        assert kern.wait().optimized
    assert optimized.read_bytes() == genuine[optimized]  # rebuilt, byte for byte
    np.testing.assert_array_equal(np.asarray(again.trajectory.coords()), got)


def test_a_system_whose_libraries_the_cache_cannot_check_is_refused_by_name(monkeypatch):
    """On a machine the ELF check does not know, the C engine refuses before building anything: "auto" warns
    and runs XLA, "c" raises, each naming the machine."""
    import platform

    from liemef.codegen import _elf, _kernel
    from liemef.engines import EngineWarning

    monkeypatch.setattr(platform, "machine", lambda: "ppc64le")
    monkeypatch.setattr(_kernel, "_KERNELS", {})
    with pytest.raises(RuntimeError, match=r"the C engine loads ELF libraries on 64-bit Linux for x86-64 and AArch64 "
                                           r"only; this is linux on ppc64le"):
        _elf.host()
    flt = liemef.MinimumEnergyFilter(_tiny_system())
    state, ts, us, ys = flt.init(Rn[2](jnp.zeros(2)), np.eye(2)), np.arange(3.0), np.zeros((3, 1)), np.ones((3, 1))
    with pytest.warns(EngineWarning, match=r"the C engine is not available .*this is linux on ppc64le.*running with "
                                           r"XLA"):
        auto = flt.run(state, ts, us, ys, engine="auto")
    np.testing.assert_array_equal(np.asarray(auto.K), np.asarray(flt.run(state, ts, us, ys, engine="xla").K))
    with pytest.raises(RuntimeError, match="ppc64le"):
        liemef.MinimumEnergyFilter(_tiny_system()).run(state, ts, us, ys, engine="c")


# --- issue 32: parameter files and user functions ---------------------------------------------------------------
# A tuning file (`liemef run --params`) is data with a schema: a file for another system, a wrong type, a negative
# std or an unknown key is refused naming the key, and metrics.json records the file (SHA-256) and every value. A
# system's functions (dynamics, outputs, residuals) are checked where they are first traced, and at the initial
# state for NaN: each refusal names the sensor, the function and what came back, at the API and, with exit status
# 2 and no traceback, at the command line. Then the command line's own items: export-c leaves no folder when it
# fails and stops a system file that never loads (--timeout), tune refuses an empty --trials, and a folder of CSV
# logs is not called a ROS bag.
def _cli(*args):
    """``liemef ARGS`` in-process: the result, which must be an exit (no exception escaped, no traceback)."""
    from click.testing import CliRunner

    from liemef.cli import cli

    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert isinstance(res.exception, SystemExit | type(None)), res.exception
    assert "Traceback" not in res.output, res.output
    return res


def _refused(res, *words):
    """``res`` exited with status 2 and its output holds every word."""
    assert res.exit_code == 2, res.output
    for w in words:
        assert str(w) in res.output, (w, res.output)
    return res.output


def _tuning_file(**changes) -> dict:
    """A tuning file of attitude-imu with every key `liemef tune` writes, ``changes`` applied (``...``: the key
    removed)."""
    from liemef.studies import tune

    params = {n: 0.5 for n in tune.SYSTEMS["attitude-imu"]}
    data = {"format": tune.FORMAT, "system": "attitude-imu", "objective": "nll", "names": ["acc_std"],
            "order": "second", "updates": "hold", "integrator": "rkmk4", "cross_validation": tune.CROSS_VALIDATION,
            "params_from": tune.PARAMS_FROM, "params": params, "train": 1.5,
            "per_recording": {"07": 1.4, "10": 1.6},
            "folds": {"07": {"params": dict(params), "train": 1.6, "held_out": 1.4},
                      "10": {"params": dict(params), "train": 1.4, "held_out": 1.6}},
            "held_out_mean": 1.5, "train_mean": 1.5, "evaluations": 9, "elapsed_s": 3.5,
            "rest_s": {"07": 26.4, "10": 36.6}}
    for path, value in changes.items():
        *head, last = path.split("__")
        at = data
        for k in head:
            at = at[k]
        if value is ...:
            at.pop(last)
        else:
            at[last] = value
    return data


def _write_json(path, data):
    import json

    path.write_text(json.dumps(data))
    return path


VELOCITY_PARAMS = {"mag_std": 0.05, "velocity_std": 0.02}
TUNING_CASES = {
    "a file for another system": (dict(system="attitude-velocity", params=VELOCITY_PARAMS, folds=..., names=...),
                                  ["system: expected a file tuned for attitude-imu", "'attitude-velocity'"]),
    "a bool for a float": (dict(params__acc_std=True), ["params.acc_std: expected a number > 0", "true (a boolean)"]),
    "a string for a float": (dict(params__acc_std="0.1"), ["params.acc_std", '"0.1" (str)']),
    "null for a float": (dict(params__mag_std=None), ["params.mag_std", "null (NoneType)"]),
    "a list for a float": (dict(params__mag_std=[0.1]), ["params.mag_std", "[0.1] (list)"]),
    "a negative std": (dict(params__mag_std=-0.1), ["params.mag_std: expected a finite number > 0", "-0.1"]),
    "a zero std": (dict(params__gyro_std=0.0), ["params.gyro_std: expected a finite number > 0", "0.0"]),
    "a negative adaptation": (dict(params__acc_adapt=-1.0), ["params.acc_adapt", ">= 0", "-1.0"]),
    "NaN": (dict(params__bias_walk=float("nan")), ["params.bias_walk: expected a finite number", "nan"]),
    "an unknown parameter": (dict(params__acc_sdt=0.1), ["params.acc_sdt: unknown parameter of attitude-imu"]),
    "another model's parameter": (dict(params__velocity_std=0.1), ["params.velocity_std: unknown parameter"]),
    "an unknown key": (dict(comment="tuned on Monday"), ["comment: unknown key"]),
    "an unknown key of a fold": (dict(folds__07__note=1), ["folds.07.note: unknown key"]),
    "a bool in a fold": (dict(folds__10__params__acc_std=False), ["folds.10.params.acc_std", "false (a boolean)"]),
    "a fold without params": (dict(folds__07__params=...), ["folds.07: expected a fold with its params"]),
    "names of another model": (dict(names=["velocity_std"]), ["names: expected a list of names from"]),
    "a negative count": (dict(evaluations=-1), ["evaluations: expected an integer >= 0", "-1"]),
    "an unknown objective": (dict(objective="mse"), ["objective: expected one of ['truth', 'nll']", '"mse"']),
    "an unknown integrator": (dict(integrator="rk45"), ["integrator: expected one of ['rkmk4', 'rkmk2', 'lie-euler']",
                                                         '"rk45"']),
    "no system (an old file)": (dict(system=...), ["system: missing", 'add "system": "attitude-imu"']),
    "no params": (dict(params=...), ["params: missing"]),
    "another format": (dict(format="liemef-tune-0"), ["format: expected a liemef tuning file"]),
}


def test_every_key_of_a_tuning_file_is_accepted(tmp_path):
    """The schema takes every key `liemef tune` writes (tests/test_tune.py writes a real one and reads it back)
    and a 0 where a term may be off; it keeps the file's bytes' SHA-256."""
    import hashlib

    from liemef.studies import tune

    p = _write_json(tmp_path / "tune.json", _tuning_file(params__acc_adapt=0, params__dip_std=0.0))
    read = tune.read(p, system="attitude-imu")
    assert read.system == "attitude-imu" and read.sha256 == hashlib.sha256(p.read_bytes()).hexdigest()
    assert read.data["params"]["acc_adapt"] == 0 and tune.load(p) == read.data
    assert set(read.data) == set(tune.FILE_KEYS)


@pytest.mark.parametrize("case", sorted(TUNING_CASES))
def test_a_bad_tuning_file_is_refused_naming_the_key(case, tmp_path):
    from liemef.studies import tune

    changes, words = TUNING_CASES[case]
    p = _write_json(tmp_path / "tune.json", _tuning_file(**changes))
    _raises(lambda: tune.read(p, system="attitude-imu"), "params:", str(p), *words)


def test_tuned_values_are_checked_at_the_api_too():
    from liemef.studies import tune

    _raises(lambda: tune.system_from({"acc_std": True}, {}), "params.acc_std", "true (a boolean)")
    _raises(lambda: tune.system_from({"acc_std": -1.0}, {}), "params.acc_std", "> 0", "-1.0")
    _raises(lambda: tune.parameters({"nope": 1.0}, {}), "params.nope: unknown parameter")
    values = tune.parameters({"acc_std": 0.07}, {"dip": 1.0})
    assert values["acc_std"] == 0.07 and values["dip"] == 1.0 and values["norm_std"] == [0.1, 1.0]


def _imu_log(path):
    """30 samples at rest of attitude-imu's columns (gyro, unit accelerometer and magnetometer, their norms)."""
    dip = np.deg2rad(68.0)
    rows = [f"{k / 100},0.001,0,0,0,0,1,{np.cos(dip)},0,{-np.sin(dip)},9.81,43" for k in range(30)]
    path.write_text("t,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z,norm_acc,norm_mag\n"
                    + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("case", sorted(TUNING_CASES))
def test_run_refuses_a_bad_tuning_file_with_exit_2(case, tmp_path):
    changes, words = TUNING_CASES[case]
    p = _write_json(tmp_path / "tune.json", _tuning_file(**changes))
    out = _refused(_cli("run", "--system", "attitude-imu", "--params", p, "--log", _imu_log(tmp_path / "log.csv"),
                        "--out", tmp_path / "o", "--no-progress"), "'--params'", str(p), *words)
    assert "defaults of" not in out and not (tmp_path / "o").exists()


def test_run_records_the_tuning_file_and_every_value_it_used(tmp_path):
    """metrics.json's config.params: the file, its SHA-256, the names it set and the whole parameter set the
    system was built with; the description names the file, not the defaults."""
    import hashlib
    import json

    from liemef.studies import tune

    changes = {f"params__{n}": ... for n in tune.SYSTEMS["attitude-imu"] if n not in ("acc_std", "mag_std")}
    p = _write_json(tmp_path / "tune.json", _tuning_file(params__acc_std=0.05, params__mag_std=0.1, **changes))
    res = _cli("run", "--system", "attitude-imu", "--params", p, "--log", _imu_log(tmp_path / "log.csv"), "--out",
               tmp_path / "o", "--no-progress", "--no-monitor")
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    record = metrics["config"]["params"]
    assert record["file"] == str(p) and record["sha256"] == hashlib.sha256(p.read_bytes()).hexdigest()
    assert record["system"] == "attitude-imu" and record["from_file"] == ["acc_std", "mag_std"]
    assert record["values"] == tune.parameters({"acc_std": 0.05, "mag_std": 0.1}, {})
    assert record["values"]["acc_std"] == 0.05 and record["values"]["gyro_std"] > 0  # a default, recorded
    description = metrics["system"]["description"]
    assert "defaults of" not in description and str(p) in description and record["sha256"][:12] in description
    assert record["updates"] == "hold" and "was tuned with updates" not in res.output  # as the run
    # a file tuned with discrete updates, run held: said, with the option that runs it as it was tuned
    p = _write_json(tmp_path / "discrete.json", _tuning_file(updates="discrete", params__acc_std=0.05, **changes))
    res = _cli("run", "--system", "attitude-imu", "--params", p, "--log", tmp_path / "log.csv", "--out",
               tmp_path / "o2", "--no-progress", "--no-monitor")
    assert res.exit_code == 0, res.output
    assert f"WARNING: the tuning file {p} was tuned with updates='discrete' and this run used 'hold'" in res.output
    assert "--updates discrete runs as it was tuned" in res.output
    # a file tuned with RKMK2, run with the default RKMK4: said; run with RKMK2: not. A file that does not say
    # was tuned with RKMK4 (liemef tune ran no other before it said): run with RKMK2, said; its record stays null
    p = _write_json(tmp_path / "rkmk2.json", _tuning_file(integrator="rkmk2", params__acc_std=0.05, **changes))
    old = _write_json(tmp_path / "old.json", _tuning_file(integrator=..., params__acc_std=0.05, **changes))
    cases = ((p, (), "o3", "rkmk2", "rkmk4"), (p, ("--integrator", "rkmk2"), "o4", None, None),
             (old, ("--integrator", "rkmk2"), "o5", "rkmk4", "rkmk2"), (old, (), "o6", None, None))
    for file, extra, out, was, used in cases:
        res = _cli("run", "--system", "attitude-imu", "--params", file, "--log", tmp_path / "log.csv", "--out",
                   tmp_path / out, "--no-progress", "--no-monitor", *extra)
        assert res.exit_code == 0, res.output
        said = f"WARNING: the tuning file {file} was tuned with integrator="
        assert (said in res.output) == (was is not None), (out, res.output)
        if was is not None:
            assert f"integrator={was!r} and this run used {used!r}" in res.output
            assert f"--integrator {was} runs as it was tuned" in res.output
        record = json.loads((tmp_path / out / "metrics.json").read_text())["config"]["params"]["integrator"]
        assert record == ("rkmk2" if file == p else None)


# A user's SE(2) system (planar GPS): what its functions get wrong, by the function.
def _gps(g, t):
    return g.cos_sin_xy[2:4]


def _dynamics(g, u, t):
    return jnp.stack([u[1], u[0], 0.0 * u[0]])


def _user_system(fn=_gps, residual=None, dynamics=_dynamics):
    from liemef.systems import Noise, Sensor, SensorSystem

    return SensorSystem(SE2, dynamics, [Sensor("gps", fn, Noise.sample(0.5), ("x", "y"), ("m", "m"),
                                               residual=residual)],
                        Noise.density([0.01, 0.02, 0.02]), inputs=("v", "omega"))


def uses_numpy(y, h):
    return np.asarray(y - h)


def branches_on_a_value(y, h):
    return y - h if y[0] > h[0] else h - y


FUNCTION_CASES = {
    # name: (the function's role and its text in a system file, the words of the message, the chained cause)
    "a residual of the wrong shape": (("residual", "lambda y, h: (y - h)[:1]"),
                                      ["sensor 'gps': residual <lambda>", "expected shape (2,)", "got shape (1,)"],
                                      None),
    "a residual that raises": (("residual", "lambda y, h: 1 / 0"),
                               ["sensor 'gps': residual <lambda>", "failed when traced", "ZeroDivisionError"],
                               ZeroDivisionError),
    "a residual using NumPy on traced values": (("residual", "uses_numpy"),
                                                ["sensor 'gps': residual uses_numpy", "TracerArrayConversionError",
                                                 "jax.numpy"], "TracerArrayConversionError"),
    "a residual branching on a traced value": (("residual", "branches_on_a_value"),
                                               ["residual branches_on_a_value", "TracerBoolConversionError"],
                                               "TracerBoolConversionError"),
    "a scalar residual": (("residual", "lambda y, h: jnp.sum(y - h)"),
                          ["sensor 'gps': residual <lambda>", "got a scalar (shape ())"], None),
    "a complex residual": (("residual", "lambda y, h: (y - h) * (1 + 0j)"),
                           ["residual <lambda>", "expected real floating-point values, got complex values"], None),
    "an integer residual": (("residual", "lambda y, h: jnp.zeros(2, int)"), ["residual", "integer values"], None),
    "a boolean residual": (("residual", "lambda y, h: y > h"), ["residual", "boolean values"], None),
    "an output of the wrong shape": (("fn", "lambda g, t: g.cos_sin_xy[2:3]"),
                                     ["sensor 'gps': fn <lambda>", "expected shape (2,)", "gps_x, gps_y",
                                      "got shape (1,)"], None),
    "an output that raises": (("fn", "lambda g, t: g.nope"), ["sensor 'gps': fn <lambda>", "AttributeError"],
                              AttributeError),
    "an output using NumPy": (("fn", "lambda g, t: np.asarray(g.cos_sin_xy[2:4])"),
                              ["sensor 'gps': fn", "TracerArrayConversionError"], "TracerArrayConversionError"),
    "a scalar output": (("fn", "lambda g, t: jnp.sum(g.cos_sin_xy)"), ["fn <lambda>", "got a scalar"], None),
    "a complex output": (("fn", "lambda g, t: g.cos_sin_xy[2:4] * 1j"), ["fn <lambda>", "complex values"], None),
    "an output that is no array": (("fn", "lambda g, t: None"), ["fn <lambda>", "got NoneType None"], None),
    "dynamics of the wrong shape": (("dynamics", "lambda g, u, t: u"),
                                    ["dynamics <lambda>", "expected shape (3,)", "algebra of SE2", "got shape (2,)"],
                                    None),
    "dynamics that raise": (("dynamics", "lambda g, u, t: u.nope"), ["dynamics <lambda>", "failed when traced",
                                                                     "AttributeError"], AttributeError),
    "dynamics using NumPy": (("dynamics", "lambda g, u, t: np.array([float(u[0]), 0.0, 0.0])"),
                             ["dynamics <lambda>", "ConcretizationTypeError"], "ConcretizationTypeError"),
    "complex dynamics": (("dynamics", "lambda g, u, t: jnp.stack([u[1], u[0], 0.0 * u[0]]) * 1j"),
                         ["dynamics <lambda>", "complex values"], None),
}


@pytest.mark.parametrize("case", sorted(FUNCTION_CASES))
def test_a_bad_user_function_is_named_when_first_traced(case):
    (role, text), words, cause = FUNCTION_CASES[case]
    fn = eval(text)  # noqa: S307 - the cases' own text, shared with the system files below
    with pytest.raises(ValueError) as err:
        _user_system(**{role: fn})
    message = str(err.value)
    for w in words:
        assert w in message, (w, message)
    assert ", line " in message  # the function's file and line
    if cause is not None:  # the function's own exception, chained
        assert err.value.__cause__ is not None and (type(err.value.__cause__).__name__ == cause
                                                    if isinstance(cause, str) else
                                                    isinstance(err.value.__cause__, cause)), err.value.__cause__


def test_a_plain_system_names_its_functions():
    args = dict(B=np.eye(2), D=np.eye(1), Q=np.eye(1), R=np.eye(2), n_inputs=1)
    _raises(lambda: System(group_type=Rn[2], dynamics_fn=lambda g, u, t: 1 / 0, output_fn=lambda g, t: g.x[:1],
                           **args), "dynamics test_a_plain_system", "<lambda>", "ZeroDivisionError")
    _raises(lambda: System(group_type=Rn[2], dynamics_fn=lambda g, u, t: g.x, output_fn=lambda g, t: g.x[:1] > 0,
                           **args), "output test_a_plain_system", "boolean values")
    _raises(lambda: System(group_type=Rn[2], dynamics_fn=lambda g, u, t: g.x, output_fn=lambda g, t: g.x[0],
                           **args), "output test_a_plain_system", "expected a vector, got a scalar")


def test_what_a_one_component_sensor_may_return():
    """A scalar is one value for a one-component sensor (its output and its residual), a list of scalars is a
    vector: both are what they say, nothing is changed."""
    from liemef.systems import Noise, Sensor, SensorSystem

    sensor = Sensor("r", lambda g, t: jnp.linalg.norm(g.cos_sin_xy[2:4]), Noise.sample(0.1),
                    residual=lambda y, h: jnp.sum(y - h))
    sysm = SensorSystem(SE2, _dynamics, [sensor], Noise.density([0.01, 0.02, 0.02]), inputs=("v", "omega"))
    assert sysm.residual(jnp.array([2.0]), jnp.array([0.5])).tolist() == [1.5]
    listed = _user_system(fn=lambda g, t: [g.cos_sin_xy[2], g.cos_sin_xy[3]])
    assert listed.output(SE2.identity(), 0.0).shape == (2,)


def test_nan_at_the_initial_state_is_refused_by_init():
    """NaN shows only when a function runs: init evaluates the outputs and residuals at g0. An infinite output
    is a singularity the filter handles while no sample of its sensor is in force: it passes."""
    g0, K0 = SE2.from_coords(jnp.array([0.0, 1.0, 2.0])), np.eye(3)
    nan_residual = liemef.MinimumEnergyFilter(_user_system(residual=lambda y, h: (y - h) * jnp.nan))
    _raises(lambda: nan_residual.init(g0, K0), "sensor 'gps': residual test_nan_at_", "returned [nan nan]",
            "at y = h = [1. 2.]", "initial state", "expected finite real numbers")
    nan_output = liemef.MinimumEnergyFilter(_user_system(fn=lambda g, t: g.cos_sin_xy[2:4] * jnp.nan))
    _raises(lambda: nan_output.init(g0, K0), "sensor 'gps': fn test_nan_at_", "returned [nan nan] at the initial state",
            "not NaN")
    inf_output = liemef.MinimumEnergyFilter(_user_system(fn=lambda g, t: g.cos_sin_xy[2:4] / 0.0))
    assert inf_output.init(g0, K0).K.shape == (3, 3)


def nan_at_speed(g, u, t):
    return _dynamics(g, u, t) * jnp.where(u[0] > 0.5, jnp.nan, 1.0)


def test_a_run_that_turns_non_finite_names_the_function():
    """NaN dynamics (at run time, with an input) fail the run as non-finite, and the message names the
    function and what it returned at the last good state; failure.json holds no NaN."""
    import json

    from liemef.studies import logs

    source = logs.LogSystem(_user_system(dynamics=nan_at_speed), "nan-dynamics", "dynamics NaN above 0.5 m/s")
    ts = 0.1 * np.arange(6)
    log = io.RecordedLog(ts, np.tile([1.0, 0.0], (6, 1)), np.full((6, 2), np.nan))
    run = logs.filter_log(source, log, x0=np.array([0.0, 1.0, 2.0]), K0=1.0)
    assert not run.ok and "dynamics nan_at_speed" in run.message and "returned [nan nan nan] at the last good state" \
        in run.message and "with the input [1. 0.]" in run.message, run.message
    json.dumps(run.failure, allow_nan=False)


SYSTEM_FILE_HEAD = """
import jax.numpy as jnp, numpy as np
from liemef.groups import SE2
from liemef.systems import Noise, Sensor, SensorSystem

def uses_numpy(y, h):
    return np.asarray(y - h)

def branches_on_a_value(y, h):
    return y - h if y[0] > h[0] else h - y

fn, residual = (lambda g, t: g.cos_sin_xy[2:4]), None
dynamics = lambda g, u, t: jnp.stack([u[1], u[0], 0.0 * u[0]])
"""
SYSTEM_FILE_TAIL = """
system = SensorSystem(SE2, dynamics, [Sensor("gps", fn, Noise.sample(0.5), ("x", "y"), ("m", "m"),
                                             residual=residual)],
                      Noise.density([0.01, 0.02, 0.02]), inputs=("v", "omega"))
x0 = [0.0, 1.0, 2.0]
"""
FILE_CASES = {**{k: (v[0], v[1]) for k, v in FUNCTION_CASES.items()},
              "a NaN residual": (("residual", "lambda y, h: (y - h) * jnp.nan"),
                                 ["sensor 'gps': residual <lambda>", "returned [nan nan] at y = h"]),
              "a NaN output": (("fn", "lambda g, t: g.cos_sin_xy[2:4] * jnp.nan"),
                               ["sensor 'gps': fn <lambda>", "returned [nan nan] at the initial state"])}


@pytest.fixture(scope="module")
def gps_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("gps") / "log.csv"
    rows = [f"{0.1 * k},1,0,{1 + 0.1 * k if k % 5 == 0 else ''},{2 if k % 5 == 0 else ''}" for k in range(20)]
    path.write_text("t,v,omega,gps_x,gps_y\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("case", sorted(FILE_CASES))
def test_run_names_a_bad_user_function_with_exit_2(case, tmp_path, gps_log):
    (role, text), words = FILE_CASES[case]
    p = tmp_path / "gps.py"
    p.write_text(SYSTEM_FILE_HEAD + f"{role} = {text}\n" + SYSTEM_FILE_TAIL)
    out = _refused(_cli("run", "--system-file", p, "--log", gps_log, "--out", tmp_path / "o", "--no-progress"),
                   *words)
    assert "gps.py, line" in out and not (tmp_path / "o").exists()


# The command line's own items.
HANGS = {"a loop": "while True:\n    pass\n",
         "a loop that holds every exception": "while True:\n    try:\n        pass\n    except Exception:\n"
                                              "        pass\n"}


@pytest.mark.parametrize("body", sorted(HANGS))
def test_a_system_file_that_never_loads_is_stopped(body, tmp_path):
    p = tmp_path / "hang.py"
    p.write_text(HANGS[body])
    _raises(lambda: load_system_file(p, timeout=0.2), "--system-file", str(p), "did not finish within 0.2 s",
            "--timeout")
    out = _refused(_cli("export-c", "--system-file", p, "--timeout", "0.2", "--out", tmp_path / "a" / "b"),
                   str(p), "did not finish within 0.2 s", "--timeout SECONDS")
    assert "0: no limit" in out and not (tmp_path / "a").exists()
    _refused(_cli("schema", "--system-file", p, "--timeout", "0.2"), "did not finish")


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_a_bad_timeout_is_refused(value, tmp_path):
    from liemef.studies import runs

    _raises(lambda: _validate.timeout("--timeout", float(value)), "--timeout", "expected seconds >= 0")
    with pytest.raises(ValueError, match=r"expected seconds >= 0 \(0: no limit\)") as err:
        runs.export_c_to(tmp_path / "c", system="tse2", timeout=float(value))
    assert err.value.option == "--timeout"
    _refused(_cli("export-c", "--system", "tse2", "--timeout", value, "--out", tmp_path / "c"), "'--timeout'",
             "expected seconds >= 0 (0: no limit)")
    assert not (tmp_path / "c").exists()


def test_a_failed_export_leaves_no_folder_it_created(tmp_path):
    from liemef.studies import runs

    bad = tmp_path / "bad.py"
    bad.write_text("raise RuntimeError('no system today')\n")
    _raises(lambda: runs.export_c_to(tmp_path / "x" / "y", system_file=bad), "RuntimeError: no system today")
    assert not (tmp_path / "x").exists()
    _refused(_cli("export-c", "--system-file", bad, "--out", tmp_path / "x" / "y"), "no system today")
    _refused(_cli("export-c", "--out", tmp_path / "x"), "expected exactly one of --system")
    _refused(_cli("export-c", "--system", "tse2", "--integrator", "euler", "--out", tmp_path / "x"), "--integrator")
    assert not (tmp_path / "x").exists()
    (tmp_path / "mine").mkdir()  # a folder that was there stays
    _refused(_cli("export-c", "--system-file", bad, "--out", tmp_path / "mine"), "no system today")
    assert (tmp_path / "mine").is_dir()


@pytest.mark.parametrize(("args", "option"), [(["--trials", ""], "--trials"), (["--trials", "07,,10"], "--trials"),
                                              (["--params", ""], "--params"), (["--params", "acc_std, "], "--params")])
def test_tune_refuses_an_empty_list(args, option, tmp_path):
    from liemef.studies import runs
    from liemef.studies.settings import OptionError

    with pytest.raises(OptionError) as err:
        runs.tune_to(tmp_path / "t", **{"trials" if option == "--trials" else "names": args[1].split(",")})
    assert err.value.option == option and "separated by commas" in str(err.value)
    _refused(_cli("tune", "broad", *args, "--out", tmp_path / "t"), f"'{option}'", "separated by commas")
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize(("start", "words"), [
    ("acc_std", "expected NAME=VALUE entries"), ("acc_std=x", "acc_std: expected a number, got 'x'"),
    ("acc_std=1,acc_std=2", "acc_std: given twice"), ("nope=1", "--start.nope: unknown parameter of attitude-imu"),
    ("acc_std=-1", "--start.acc_std: expected a finite number > 0, got -1.0"), ("acc_std=1,", "separated by commas"),
    ("velocity_std=1", "--start.velocity_std: unknown parameter of attitude-imu")])
def test_tune_refuses_a_bad_start(start, words, tmp_path):
    from liemef.studies import runs
    from liemef.studies.settings import OptionError

    with pytest.raises(OptionError) as err:
        runs.tune_to(tmp_path / "t", start=start.split(","))
    assert err.value.option == "--start" and words in str(err.value)
    _refused(_cli("tune", "broad", "--start", start, "--out", tmp_path / "t"), "'--start'", words)
    assert not (tmp_path / "t").exists()


def test_a_folder_of_csv_logs_is_no_ros_bag(tmp_path, gps_log):
    folder = tmp_path / "logs"
    folder.mkdir()
    (folder / "a.csv").write_text(gps_log.read_text())
    assert not io.is_bag(folder) and not io.is_bag(folder / "a.csv")
    out = _refused(_cli("run", "--system", "localization", "--log", folder, "--out", tmp_path / "o"), "'--log'",
                   "got the folder", "without a metadata.yaml", "'a.csv': give one of them")
    assert "is a ROS bag" not in out
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (tmp_path / "old.bag").write_bytes(b"")
    assert io.is_bag(folder) and io.is_bag(folder / "metadata.yaml") and io.is_bag(tmp_path / "old.bag")
    _refused(_cli("run", "--system", "localization", "--log", folder, "--out", tmp_path / "o"), "'--topics'",
             "is a ROS bag: give --topics")


# --- issue 32: engines ---------------------------------------------------------------------------------------
# The C engine gives XLA's result bit for bit where IEEE 754 or LAPACK leaves a choice (NaN propagation, signed
# zeros, an eigenvector's sign), or refuses the primitive by name with the user's line; a while_loop that the
# second-order filter would differentiate in reverse mode is refused when the filter is made (docs/engines.md).
import ctypes  # noqa: E402
import subprocess  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402

from liemef import codegen  # noqa: E402
from liemef.systems import Noise, Sensor, SensorSystem  # noqa: E402

needs_cc = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")

# f: R^2 -> R^k, each about one choice; the C of f, jacfwd(f) and hessian(f) against XLA's at every SPECIAL point
EDGE_FUNCTIONS = {
    "atan2_of_zero_times_x": lambda x: jnp.stack([jnp.arctan2(0.0 * x[0], -1.0), jnp.arctan2(x[1] * 0.0, -1.0)]),
    "zero_times_nan": lambda x: jnp.stack([0.0 * x[0] + x[1], jnp.sin(x[0]) * x[1] + x[0] * x[0]]),
    "plus_zero_of_minus_zero": lambda x: jnp.stack([x[0] + 0.0, x[1] - 0.0, 0.0 - x[0],
                                                    x[1] + jnp.array([0.0, 1.0])[0]]),
    "max_min_of_signed_zeros": lambda x: jnp.stack([jnp.maximum(x[0], 0.0), jnp.minimum(0.0, x[1]),
                                                    jnp.clip(x[0], -0.0, 1.0), jnp.max(jnp.stack([x[1], -x[1]]))]),
    "sums_of_zeros": lambda x: jnp.stack([jnp.sum(x * 0.0), jnp.dot(x, jnp.zeros(2)), jnp.cumsum(0.0 * x)[1]]),
    "mask_times_nan": lambda x: x * (x > 0.5).astype(jnp.float64) + jnp.sqrt(x) * x[::-1],
    "division_and_log": lambda x: jnp.stack([1.0 / x[0], jnp.log(x[1] * x[1]), x[0] / (x[1] - x[1])]),
}
SPECIAL = (-0.0, 0.0, np.inf, -np.inf, np.nan)
EDGE_FORMS = {"value": lambda f: f, "jacfwd": jax.jacfwd, "hessian": jax.hessian}


@pytest.fixture(scope="module")
def edge_library(tmp_path_factory):
    """Every EDGE_FUNCTIONS form in one C source by the engine's translator, compiled once."""
    from liemef.codegen._primitives import helpers_used
    from liemef.codegen._scalar_c import ScalarTranslator, scalar_jaxpr_to_c

    tr, texts, sizes = ScalarTranslator(), [], {}
    for name, f in EDGE_FUNCTIONS.items():
        for form, d in EDGE_FORMS.items():
            closed = jax.make_jaxpr(d(f))(jnp.zeros(2))
            text, tr = scalar_jaxpr_to_c(f"{name}_{form}", closed, ["x"], ["o"], translator=tr)
            sizes[f"{name}_{form}"] = int(np.prod(closed.jaxpr.outvars[0].aval.shape))
            texts.append(text + f"void call_{name}_{form}(const double *x, double *o) {{ {name}_{form}(x, o); }}\n")
    code = "\n".join(tr.table_lines + texts)
    d = tmp_path_factory.mktemp("edges")
    (d / "e.c").write_text("#include <math.h>\n#include <stdint.h>\n" + helpers_used(code) + "\n" + code)
    subprocess.run([codegen.compiler(), "-std=c99", "-O2", "-shared", "-fPIC", "-o", str(d / "e.so"), str(d / "e.c")],
                   check=True, capture_output=True)
    return ctypes.CDLL(str(d / "e.so")), sizes


@needs_cc
@pytest.mark.parametrize("form", sorted(EDGE_FORMS))
@pytest.mark.parametrize("name", sorted(EDGE_FUNCTIONS))
def test_c_gives_xlas_nan_infinities_and_signed_zeros(edge_library, name, form):
    lib, sizes = edge_library
    fn = jax.jit(EDGE_FORMS[form](EDGE_FUNCTIONS[name]))
    for a in SPECIAL + (-1.5, 2.0):
        for b in SPECIAL + (0.75,):
            x = np.array([a, b])
            want = np.asarray(fn(jnp.asarray(x)), np.float64).ravel()
            got = np.full(sizes[f"{name}_{form}"], 7.0)
            getattr(lib, f"call_{name}_{form}")(x.ctypes.data_as(ctypes.c_void_p), got.ctypes.data_as(ctypes.c_void_p))
            where = f"{name} {form} at {x}: C {got}, XLA {want}"
            assert np.array_equal(np.isnan(got), np.isnan(want)), where
            fin = ~np.isnan(want)
            assert np.array_equal(np.signbit(got[fin & (want == 0)]), np.signbit(want[fin & (want == 0)])), where
            np.testing.assert_allclose(got[fin], want[fin], rtol=1e-14, atol=0, err_msg=where)


@needs_cc
def test_atan2_of_zero_times_a_negative_is_minus_pi_in_c(edge_library):
    """The issue's case: C folded 0.0 * x to +0, so atan2(0.0 * x, -1) was +pi where XLA's is -pi for x < 0."""
    lib, _ = edge_library
    x, got = np.array([-2.0, 3.0]), np.zeros(2)
    lib.call_atan2_of_zero_times_x_value(x.ctypes.data_as(ctypes.c_void_p), got.ctypes.data_as(ctypes.c_void_p))
    assert got.tolist() == [-np.pi, np.pi]


def _cart_system(h, p=1):
    return SensorSystem(Rn[2], lambda g, u, t: jnp.stack([g.x[1], u[0] - 0.3 * g.x[1]]),
                        [Sensor("range", h, Noise.sample(0.05 * np.ones(p)))],
                        process_noise=Noise.density([0.05, 0.2]), inputs=("throttle",))


def _cart_log(n=5):
    ts = 0.02 * np.arange(n)
    return ts, 0.5 * np.ones((n, 1)), np.full((n, 1), 1.2)


def eigh_output(g, t):
    M = jnp.array([[2.0 + g.x[0] ** 2, 0.3 * g.x[1]], [0.3 * g.x[1], 1.0]])
    return jnp.linalg.eigh(M)[1][:, 0] * g.x[0]  # an eigenvector: its sign is LAPACK's choice


def eigvalsh_output(g, t):
    return jnp.linalg.eigvalsh(jnp.diag(g.x) + 0.1)[1:]  # eigenvalues alone: their derivatives read eigenvectors


@needs_cc
@pytest.mark.parametrize(("fn", "p"), [(eigh_output, 2), (eigvalsh_output, 1)])
def test_a_users_eigh_is_refused_on_c_by_name_and_line(fn, p):
    flt = liemef.MinimumEnergyFilter(_cart_system(fn, p))
    state = flt.init(Rn[2](jnp.array([1.0, 0.5])), np.eye(2))
    ts, us, ys = _cart_log()
    ys = np.ones((len(ts), p))
    line = fn.__code__.co_firstlineno + 1 + (fn is eigh_output)
    where = f"{Path(__file__).name}:{line} ({fn.__name__})"
    with pytest.raises(codegen.UnsupportedPrimitive) as err:
        flt.run(state, ts, us, ys, engine="c")
    assert "eigh" in str(err.value) and "LAPACK's choice" in str(err.value) and where in str(err.value), str(err.value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", liemef.engines.LogGapWarning)
        with pytest.warns(liemef.engines.EngineWarning) as record:
            auto = flt.run(state, ts, us, ys)
    text = str(record[0].message)
    assert "eigh" in text and where in text and "running with XLA" in text, text
    xla = flt.run(state, ts, us, ys, engine="xla")
    assert np.array_equal(np.asarray(auto.final.K), np.asarray(xla.final.K))


def test_a_users_svd_is_refused_by_name_and_line():
    from liemef.codegen._scalar_c import scalar_jaxpr_to_c

    def singular(x):
        return jnp.linalg.svd(jnp.outer(x, x), compute_uv=False)  # no C: refused

    line = singular.__code__.co_firstlineno + 1
    with pytest.raises(codegen.UnsupportedPrimitive, match=rf"'svd'.*{Path(__file__).name}:{line} \(.*singular\)"):
        scalar_jaxpr_to_c("k", jax.make_jaxpr(jax.jacfwd(singular))(jnp.ones(2)), ["x"], ["o"])


@needs_cc
def test_the_ukfs_own_eigh_agrees_at_a_repeated_eigenvalue():
    """liemef's own eigh is translated: the UKF-M's symmetric square root of P does not depend on the
    eigenvectors picked, so a P with a repeated eigenvalue (a rotated diag(0.1, 0.1, 0.3)) gives XLA's run."""
    from liemef.filters.baselines import UnscentedKalmanFilter

    sysm = planar_localization()
    flt = UnscentedKalmanFilter(sysm)
    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    state = flt.init(SE2.identity(), Q @ np.diag([0.1, 0.1, 0.3]) @ Q.T)
    n = 20
    ts = 0.01 * np.arange(n)
    us = 0.3 + 0.1 * rng.standard_normal((n, sysm.input_dim))
    ys = 0.05 * rng.standard_normal((n, sysm.output_dim))
    with warnings.catch_warnings():
        warnings.simplefilter("error", liemef.engines.EngineWarning)
        c = flt.run(state, ts, us, ys, engine="c")
    x = flt.run(state, ts, us, ys, engine="xla")
    # rounding apart (Jacobi's and LAPACK's eigenvalues): V sqrt(W) by LAPACK's eigenvectors and by Jacobi's
    # differed by 8e-11 of K here, a rotation of the sigma points in the repeated eigenvalue's eigenspace
    K = np.asarray(x.final.K)
    np.testing.assert_allclose(np.asarray(c.final.K), K, rtol=0, atol=1e-12 * np.abs(K).max())
    np.testing.assert_allclose(np.asarray(c.coords()), np.asarray(x.coords()), rtol=0, atol=1e-12)


def _while_h(g, t):
    def body(c):
        return c[0] + 1, c[1] - 0.1 * (c[1] - g.x[0])
    return jax.lax.while_loop(lambda c: c[0] < 5, body, (0, g.x[0]))[1][None]  # on the state


def _traced_bounds_h(g, t):
    n = jnp.clip(jnp.floor(g.x[1] + 3.0), 1, 5).astype(jnp.int32)
    return jax.lax.fori_loop(0, n, lambda i, x: x - 0.1 * (x - g.x[0]), g.x[0])[None]  # traced bounds: a while


@pytest.mark.parametrize("fn", [_while_h, _traced_bounds_h])
def test_a_while_loop_on_the_state_in_an_output_is_refused_when_the_filter_is_made(fn):
    line = fn.__code__.co_firstlineno + (3 if fn is _while_h else 2)
    sysm = _cart_system(fn)
    _raises(lambda: liemef.MinimumEnergyFilter(sysm), "sensor 'range': h(g, t)", "lax.while_loop on the state",
            f"{Path(__file__).name}:{line} ({fn.__name__})", "jax.hessian", "lax.fori_loop with Python int bounds",
            'order="first"')
    _raises(lambda: liemef.MinimumEnergyFilter(sysm, updates="discrete"), "lax.while_loop on the state")
    liemef.MinimumEnergyFilter(sysm, order="first")  # differentiates the output once: forward mode, fine


def test_a_while_loop_in_a_plain_systems_output_is_named_as_the_output():
    sysm = System(group_type=Rn[2], dynamics_fn=lambda g, u, t: jnp.zeros(2), output_fn=_while_h, B=np.eye(2),
                  D=np.eye(1), Q=np.eye(1), R=np.eye(2))
    _raises(lambda: liemef.MinimumEnergyFilter(sysm), "output h(g, t)", "lax.while_loop on the state", "_while_h")


def test_a_while_loop_the_state_enters_by_its_test_alone_is_not_refused():
    def h(g, t):  # the loop's count depends on the state, its values do not: nothing to differentiate through it
        scale = jax.lax.while_loop(lambda c: c[0] < g.x[1] + 3.0, lambda c: (c[0] + 1.0, 0.5 * c[1]), (0.0, 1.0))[1]
        return g.x[:1] + jax.lax.stop_gradient(scale)

    def dyn(g, u, t):  # the dynamics are differentiated forward (jacfwd): a while on the state is fine there
        return jnp.stack([jax.lax.while_loop(lambda c: c[0] < 3, lambda c: (c[0] + 1, 0.9 * c[1]), (0, g.x[1]))[1],
                          u[0]])

    liemef.MinimumEnergyFilter(_cart_system(h))
    liemef.MinimumEnergyFilter(SensorSystem(Rn[2], dyn, [Sensor("range", lambda g, t: g.x[:1], Noise.sample([0.05]))],
                                            process_noise=Noise.density([0.05, 0.2]), inputs=("throttle",)))


def test_a_matrix_groups_log_in_an_output_is_not_refused():
    """MatrixGroup.log starts its Newton polish from logm (while loops) of stop_gradient(g): JAX takes its Hessian
    (the Newton map's), so the filter takes it too."""
    from liemef.groups import SO3, MatrixGroup

    G = MatrixGroup.from_basis("SO3FromBasis", np.asarray(SO3.hat(jnp.eye(3))))
    sysm = System(group_type=G, dynamics_fn=lambda g, u, t: u, output_fn=lambda g, t: g.log(), B=0.1 * np.eye(3),
                  D=0.1 * np.eye(3), Q=np.eye(3), R=np.eye(3), n_inputs=3)
    liemef.MinimumEnergyFilter(sysm)
    g = G.exp(jnp.array([0.1, -0.2, 0.3]))
    H = jax.eval_shape(jax.hessian(lambda xi: sysm.output(g.rplus(xi), 0.0)[0]), jnp.zeros(3))
    assert H.shape == (3, 3)


def test_a_negative_zero_parameter_is_read_at_run_time_not_folded():
    """The kernel folds a parameter's +0 entries (its zero pattern); a -0 is read at run time, else its sign
    would be lost in a product."""
    from liemef.codegen._scalar_c import structural_zero

    assert structural_zero(np.array([0.0, -0.0, 1.0, np.nan])).tolist() == [True, False, False, False]


CLI_SYSTEM = """import jax, jax.numpy as jnp
from liemef.groups import Rn
from liemef.systems import Noise, Sensor, SensorSystem


def h(g, t):
    return {body}


system = SensorSystem(Rn[2], lambda g, u, t: jnp.stack([g.x[1], u[0]]), [Sensor("range", h, Noise.sample([0.05]))],
                      process_noise=Noise.density([0.05, 0.2]), inputs=("throttle",))
"""
CLI_BODIES = {
    "while_loop": "jax.lax.while_loop(lambda c: c[0] < 5, lambda c: (c[0] + 1, 0.9 * c[1] + 0.1 * g.x[0]), "
                  "(0, g.x[0]))[1][None]",
    "eigh": "jnp.linalg.eigh(jnp.diag(g.x) + 0.1)[1][:1, 0] * g.x[0]",
}


def _cli_run(tmp_path, body):
    from click.testing import CliRunner

    from liemef.cli import cli

    (tmp_path / "sys.py").write_text(CLI_SYSTEM.format(body=CLI_BODIES[body]))
    io.write_log(tmp_path / "log.csv", _cart_system(lambda g, t: g.x[:1]), 0.02 * np.arange(10), np.zeros((10, 1)),
                 np.ones((10, 1)))
    args = ["run", "--system-file", str(tmp_path / "sys.py"), "--log", str(tmp_path / "log.csv"), "--out",
            str(tmp_path / "o"), "--x0", "1,0", "--no-progress"]
    return CliRunner().invoke(cli, args)


def test_cli_a_while_loop_in_a_system_files_output_exits_saying_what_to_use(tmp_path):
    res = _cli_run(tmp_path, "while_loop")
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    for words in ("sensor 'range': h(g, t)", "lax.while_loop on the state", f"{tmp_path / 'sys.py'}:7 (h)",
                  "lax.fori_loop with Python int bounds", 'order="first"'):
        assert words in res.output, (words, res.output)
    assert not (tmp_path / "o").exists()


@needs_cc
def test_cli_an_eigh_in_a_system_files_output_runs_with_xla_naming_it(tmp_path):
    with pytest.warns(liemef.engines.EngineWarning) as record:
        res = _cli_run(tmp_path, "eigh")
    assert res.exit_code == 0, res.output
    text = " ".join(str(r.message) for r in record if r.category is liemef.engines.EngineWarning)
    assert "eigh" in text and "LAPACK's choice" in text and f"{tmp_path / 'sys.py'}:7 (h)" in text and \
        "running with XLA" in text, text
    assert (tmp_path / "o" / "estimates.csv").exists()
