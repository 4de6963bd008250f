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


def _raises(fn, *words):
    """``fn()`` raises a ValueError (not another type) whose message holds every word (regex-escaped)."""
    with pytest.raises(ValueError) as err:
        fn()
    assert type(err.value) is ValueError
    for w in words:
        assert re.search(re.escape(str(w)), str(err.value)), (w, str(err.value))
    return str(err.value)


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


def _filter(path, **kw):
    from liemef.studies import logs

    return logs.filter_log("localization", path, x0=np.zeros(3), updates="discrete", **kw)


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
    assert "filter failed over the sample interval 50 ([0.5, 0.51] s): the gain K lost positive definiteness" in \
        res.output and "condition number of" in res.output and "gps 0." in res.output
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["failure.json"]
    failure = io.read_json(tmp_path / "o" / "failure.json")
    assert failure["interval"]["K_condition"] > 1e12 and failure["interval"]["gap"] is False
    assert failure["interval"]["samples"]["gps"]["components"] == ["gps_x", "gps_y"]
    assert all(np.isfinite(list(failure["last_good_state"]["coords"].values())))


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
    from liemef.codegen._jaxpr_c import helpers_used
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
