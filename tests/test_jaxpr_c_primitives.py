"""The C translator, one primitive at a time (issue 22): each primitive a user's system may hold, on data known
only at run time, against XLA, in value and under ``jacfwd`` and ``hessian`` (the filter differentiates the user's
dynamics and outputs twice, so every primitive of the differentiated jaxprs must translate too).

Every case is a small function f: R^n -> R^k of everyday JAX (``x[i]`` with a traced i, ``jnp.interp``, ``sort``,
``expm``, ...), and each names the primitives it is about; a test checks that they are in the traced jaxprs at run
time (so that a case cannot pass by folding away). All cases and forms are translated by the scalar translator
(the engine's) into one C source, compiled once with ``-std=c99 -O0 -Wall -Wextra -Werror -pedantic`` and
called through ctypes at random inputs. The same source compiles warning-free with GCC and Clang.
"""

from __future__ import annotations

import ctypes
import re
import subprocess
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from compilers import COMPILERS, compiler_or_skip, warning_free_flags
from liemef import codegen
from liemef.codegen._jaxpr_c import Translator, jaxpr_to_c
from liemef.codegen._primitives import helpers_used
from liemef.codegen._scalar_c import ScalarTranslator, scalar_jaxpr_to_c
from tolerances import PRIMITIVE_C

pytestmark = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC, cc, gcc or clang)")

FLAGS = ("-std=c99", "-O0", "-Wall", "-Wextra", "-Werror", "-pedantic")
TABLE = jnp.array([0.3, -1.2, 2.5, 0.7, 1.1, -0.4])
LONG_TABLE = jnp.sin(jnp.arange(40.0)) * jnp.arange(40.0)  # read as a C array (LOOKUP_MIN)
GRID = jnp.linspace(0.0, 2.0, 7)


def _index(x, k):
    """A traced integer in [0, k) from a float input (as a user's system gets one from t or the state)."""
    return jnp.clip(jnp.floor(k * (jnp.tanh(x) + 1.0) / 2.0).astype(jnp.int32), 0, k - 1)


def _spd(x, n=3):
    A = jnp.reshape(x[:n * n], (n, n))
    return A @ A.T + n * jnp.eye(n)


def _ints(x):
    """Two int32 numerators and denominators from the inputs (truncated: at random inputs some denominators are
    0, where C's division is undefined and XLA's gives -1, and the remainder the numerator)."""
    return x[:2].astype(jnp.int32), x[2:4].astype(jnp.int32)


def _turned(x):
    """A 2 x 2 matrix R(2 x0) diag(2 + x1^2, 2 + x2^2): never singular, and its LU swaps the rows where the
    rotation's sine outweighs its cosine (half of the random inputs)."""
    c, s = jnp.cos(2.0 * x[0]), jnp.sin(2.0 * x[0])
    return jnp.array([[c, -s], [s, c]]) * jnp.stack([2.0 + x[1] ** 2, 2.0 + x[2] ** 2])


def _scan_body(c, a):
    return c * jnp.cos(a) + jnp.sin(c), c * a


# name: (f, n, primitives that must be in the jaxprs of f, jacfwd(f) and hessian(f) together)
CASES = {
    "table_by_traced_int": (lambda x: TABLE[_index(x[0], 6)] * x[1] ** 2 + x[0], 2, {"dynamic_slice"}),
    "long_table": (lambda x: LONG_TABLE[_index(x[0], 40)] * x[1] + jnp.take(LONG_TABLE, _index(x[1], 45) - 2) * x[0],
                   2, {"dynamic_slice", "gather"}),
    "index_traced": (lambda x: x[_index(x[0], 4)] * x[1] + x[_index(x[2], 4)] ** 2, 4, {"dynamic_slice"}),
    "take_fill": (lambda x: jnp.take(x, jnp.stack([_index(x[0], 4), _index(x[1], 4)])) * x[2], 4,
                  {"gather", "scatter-add"}),
    "take_out_of_range": (lambda x: jnp.take(x, _index(x[0], 4) + 2) * x[1] + x[2], 4, {"gather"}),
    "take_along_axis": (lambda x: jnp.take_along_axis(jnp.reshape(x, (2, 3)) ** 2,
                                                      jnp.argsort(jnp.reshape(x, (2, 3)), axis=1), axis=1).ravel(),
                        6, {"gather", "sort"}),
    "gather_2d": (lambda x: jnp.reshape(x, (3, 3))[_index(x[0], 3), _index(x[4], 3)] * x[8], 9,
                  {"dynamic_slice"}),
    "dynamic_slice_window": (lambda x: jax.lax.dynamic_slice(jnp.reshape(x, (3, 3)), (_index(x[0], 3),
                                                                                     _index(x[1], 3)), (2, 2)) * x[2],
                             9, {"dynamic_slice"}),
    "dynamic_update_slice": (lambda x: jax.lax.dynamic_update_slice(x, jnp.sin(x[:2]) * x[3], (_index(x[0], 4),)),
                             4, {"dynamic_update_slice"}),
    "scatter_set": (lambda x: x.at[_index(x[0], 4)].set(x[1] * x[2]) * x[3], 4, {"scatter"}),
    "scatter_add": (lambda x: (x ** 2).at[jnp.stack([_index(x[0], 4), _index(x[1], 4)])].add(x[2:4] * x[0]), 4,
                    {"scatter-add"}),
    "argmax": (lambda x: x[jnp.argmax(x)] * x[0] + jnp.argmax(x).astype(float), 4, {"argmax"}),
    "argmin": (lambda x: x[jnp.argmin(jnp.sin(x))] ** 3 + jnp.argmin(x, axis=0).astype(float), 4, {"argmin"}),
    "argmax_rows": (lambda x: jnp.argmax(jnp.reshape(x, (2, 3)), axis=1) * x[:2], 6, {"argmax"}),
    "sort": (lambda x: jnp.sort(x) * jnp.arange(1.0, 6.0), 5, {"sort"}),
    "sort_rows": (lambda x: jnp.sort(jnp.reshape(x, (2, 3)) ** 3, axis=1).ravel(), 6, {"sort"}),
    "argsort": (lambda x: jnp.argsort(x).astype(float) * x[0] + x[jnp.argsort(x)[1]], 4, {"sort"}),
    "median": (lambda x: jnp.median(x) * x[0], 5, {"sort"}),
    "interp": (lambda x: jnp.interp(x[0], GRID, jnp.sin(x[1] * GRID)) * jnp.ones(2) + x[1], 2, {"lt_to"}),
    "searchsorted": (lambda x: jnp.searchsorted(GRID, x[0]).astype(float) * x[1], 2, {"le_to"}),
    "cumsum": (lambda x: jnp.cumsum(x ** 2), 4, {"cumsum"}),
    "cumsum_reverse": (lambda x: jax.lax.cumsum(jnp.reshape(x, (2, 3)) * x[0], axis=1, reverse=True).ravel(), 6,
                       {"cumsum"}),
    "cumprod": (lambda x: jnp.cumprod(x), 4, {"cumprod"}),
    "cummax": (lambda x: jax.lax.cummax(x * x[0]), 4, {"cummax"}),
    "cummin": (lambda x: jax.lax.cummin(jnp.sin(x)), 4, {"cummin"}),
    "round_even": (lambda x: jnp.round(3.0 * x) * x, 3, {"round"}),
    "round_away": (lambda x: jax.lax.round(3.0 * x) * x ** 2, 3, {"round"}),
    "elementary": (lambda x: jnp.stack([
        jnp.sin(x[0]), jnp.cos(x[1]), jnp.tan(0.3 * x[2]), jnp.arcsin(jnp.tanh(x[0])), jnp.arccos(jnp.tanh(x[1])),
        jnp.arctan(x[2]), jnp.sinh(x[0]), jnp.cosh(x[1]), jnp.tanh(x[2]), jnp.arcsinh(x[0]),
        jnp.arccosh(2.0 + x[1] ** 2), jnp.arctanh(0.5 * jnp.tanh(x[2])), jnp.exp(x[0]), jnp.exp2(x[1]),
        jnp.log(1.0 + x[2] ** 2), jnp.log1p(x[0] ** 2), jnp.expm1(x[1]), jnp.sqrt(1.0 + x[2] ** 2),
        jax.lax.rsqrt(1.0 + x[0] ** 2), jnp.cbrt(x[1]), jnp.abs(x[2]) * x[0], jnp.floor(x[0]) * x[1],
        jnp.ceil(x[1]) * x[2], jnp.square(x[2]), jax.scipy.special.erf(x[0]), jax.scipy.special.erfc(x[1]),
        jnp.sign(x[2]) * x[0], jax.nn.sigmoid(x[1]), x[0] ** 3, 1.0 / x[1] ** 2]), 3,
        {"sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh", "atanh", "exp",
         "exp2", "log", "log1p", "expm1", "sqrt", "rsqrt", "cbrt", "abs", "floor", "ceil", "square", "erf", "erfc",
         "sign", "logistic", "integer_pow"}),
    "int_div_rem": (lambda x: jnp.concatenate([jax.lax.div(*_ints(x)), jax.lax.rem(*_ints(x))]) * x[0], 4,
                    {"div", "rem"}),
    # XLA's conversion saturates and takes NaN to 0 (C's cast is undefined there): 1e10 x and 1e19 x are mostly
    # out of range, log(x) is NaN for half of the inputs
    "float_to_int": (lambda x: jnp.concatenate([(1e10 * x[:2]).astype(jnp.int32), (1e3 * x[:2]).astype(jnp.uint8),
                                                jnp.log(x[2:3]).astype(jnp.int32), (1e19 * x[3:4]).astype(jnp.int64)])
                     * x[3], 4, {"convert_element_type"}),
    # shifts by 0, 12, 24, 36 of -2 .. 3: by 32 or more XLA gives 0 (C: undefined, x86 shifts by b mod 32)
    "shift_left": (lambda x: jax.lax.shift_left(3 - _index(x[0], 6), 12 * _index(x[1], 4)) * x[0], 2,
                   {"shift_left"}),
    "binary": (lambda x: jnp.stack([
        jnp.power(1.0 + x[0] ** 2, x[1]), jnp.arctan2(x[0], x[1]), jnp.fmod(x[0], 0.7 + x[1] ** 2),
        jnp.maximum(x[0], x[1]) * x[2], jnp.minimum(x[1], x[2]) ** 2, jax.lax.clamp(-0.5, x[0], 0.8) * x[1],
        jnp.where(x[0] > x[1], x[2] ** 2, jnp.sin(x[0]))]), 3,
        {"pow", "atan2", "rem", "max", "min", "clamp", "select_n"}),
    "checkpoint": (lambda x: jax.checkpoint(lambda v: jnp.sin(v) * jnp.exp(v[0]))(x), 2, {"remat2"}),
    "optimization_barrier": (lambda x: jnp.stack(jax.lax.optimization_barrier((x[0] * x[1], jnp.sin(x[1])))), 2,
                             {"optimization_barrier"}),
    "reduce_precision_own": (lambda x: jax.lax.reduce_precision(jnp.sin(x), exponent_bits=11, mantissa_bits=52)
                             * x[0], 2, {"reduce_precision"}),
    "fori_loop": (lambda x: jax.lax.fori_loop(0, 4, lambda i, c: jnp.sin(c) * x[1] + i * c, x[0]) * jnp.ones(1),
                  2, {"scan"}),
    "scan": (lambda x: jax.lax.scan(_scan_body, x[0], x[1:])[1], 4, {"scan"}),
    "scan_reverse": (lambda x: jnp.stack(jax.lax.scan(_scan_body, x[0], x[1:], reverse=True)[1:]).ravel(), 4,
                     {"scan"}),
    "cholesky": (lambda x: jnp.linalg.cholesky(_spd(x, 2)).ravel(), 4, {"cholesky", "triangular_solve"}),
    "cholesky_indefinite": (lambda x: jnp.linalg.cholesky(jnp.array([[x[0], x[1]], [x[1], x[2]]])).ravel(), 3,
                            {"cholesky"}),
    "cho_solve": (lambda x: jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(_spd(x, 2)), x[:2]), 4,
                  {"cholesky", "triangular_solve"}),
    "solve": (lambda x: jnp.linalg.solve(_spd(x) + jnp.diag(x[:3]), x[3:6]), 9, {"lu", "triangular_solve"}),
    "lu_solve": (lambda x: jax.scipy.linalg.lu_solve(jax.scipy.linalg.lu_factor(_turned(x)), x[3:5]), 5,
                 {"lu", "lu_pivots_to_permutation", "triangular_solve"}),
    "inv": (lambda x: jnp.linalg.inv(jnp.reshape(x, (2, 2)) + 3.0 * jnp.eye(2)).ravel(), 4,
            {"lu", "triangular_solve"}),
    "expm": (lambda x: jax.scipy.linalg.expm(0.5 * jnp.reshape(x, (2, 2))).ravel(), 4, {"scan"}),
}
FORMS = ("value", "jacfwd", "hessian")
SLOW = {("expm", "hessian"), ("solve", "hessian")}
"""Forms whose C is large (expm's Hessian: 2.5 MB, 20 s to translate and compile; a 3 x 3 LU's: 0.2 MB): built
apart, in the slow suite."""


def _form(f, form):
    return {"value": f, "jacfwd": jax.jacfwd(f), "hessian": jax.hessian(f)}[form]


def _primitives(jaxpr) -> set[str]:
    names = set()
    for eqn in jaxpr.eqns:
        names.add(eqn.primitive.name)
        for v in eqn.params.values():
            for sub in v if isinstance(v, list | tuple) else [v]:
                if hasattr(sub, "jaxpr") and hasattr(sub, "consts"):
                    names |= _primitives(sub.jaxpr)
                elif hasattr(sub, "eqns"):
                    names |= _primitives(sub)
    return names


def _build(tmp_path_factory, pairs):
    """The cases and forms ``pairs`` in one C source, compiled once: (library, source, {name: output size},
    {name: primitives in its jaxpr})."""
    tr = ScalarTranslator()
    texts, sizes, prims = [], {}, {}
    for case, form in pairs:
        f, n, _ = CASES[case]
        name = f"{case}_{form}"
        closed = jax.make_jaxpr(_form(f, form))(jnp.zeros(n))
        prims[name] = _primitives(closed.jaxpr)
        text, tr = scalar_jaxpr_to_c(name, closed, ["x"], ["o"], translator=tr)
        sizes[name] = int(np.prod(closed.jaxpr.outvars[0].aval.shape, dtype=np.int64))
        texts.append(text + f"void call_{name}(const double *x, double *o) {{ {name}(x, o); }}\n")
    code = "\n".join(tr.table_lines + texts)
    source = ("#include <math.h>\n#include <stddef.h>\n#include <stdint.h>\n#include <string.h>\n"
              + helpers_used(code) + "\n" + "\n".join(f"void call_{nm}(const double *x, double *o);" for nm in sizes)
              + "\n" + code)
    d = tmp_path_factory.mktemp("primitives")
    (d / "k.c").write_text(source)
    proc = subprocess.run([codegen.compiler(), *FLAGS, "-shared", "-fPIC", "-o", str(d / "k.so"), str(d / "k.c")],
                          capture_output=True, text=True)
    assert proc.returncode == 0 and not proc.stderr, proc.stderr[:4000]
    return ctypes.CDLL(str(d / "k.so")), d / "k.c", sizes, prims


@pytest.fixture(scope="module")
def kernels(tmp_path_factory):
    return _build(tmp_path_factory, [(c, f) for c in CASES for f in FORMS if (c, f) not in SLOW])


@pytest.fixture(scope="module")
def slow_kernels(tmp_path_factory):
    return _build(tmp_path_factory, sorted(SLOW))


def _call(lib, name, x, size):
    out = np.full(size, np.nan)
    x = np.ascontiguousarray(x, np.float64)
    getattr(lib, f"call_{name}")(x.ctypes.data_as(ctypes.c_void_p), out.ctypes.data_as(ctypes.c_void_p))
    return out


@pytest.mark.parametrize(("case", "form"), [
    pytest.param(c, f, marks=[pytest.mark.slow] if (c, f) in SLOW else []) for c in sorted(CASES) for f in FORMS])
def test_primitive_in_c_equals_xla(request, case, form):
    lib, _, sizes, _ = request.getfixturevalue("slow_kernels" if (case, form) in SLOW else "kernels")
    f, n, _ = CASES[case]
    fn = jax.jit(_form(f, form))
    rng = np.random.default_rng(zlib.crc32(case.encode()))  # the same inputs in every process (hash() is salted)
    for _ in range(5):
        x = rng.normal(size=n) * 1.5
        want = np.asarray(fn(jnp.asarray(x)), np.float64).ravel()
        got = _call(lib, f"{case}_{form}", x, sizes[f"{case}_{form}"])
        # NaN where XLA has NaN (a derivative's structural zero times a NaN too), and zeros of XLA's signs
        assert np.array_equal(np.isnan(got), np.isnan(want)), f"NaN at other places\nC   {got}\nXLA {want}"
        zeros = (got == 0) & (want == 0)
        assert np.array_equal(np.signbit(got[zeros]), np.signbit(want[zeros])), \
            f"zeros of other signs\nC   {got}\nXLA {want}"
        ok = ~np.isnan(want)
        err = np.abs(got[ok] - want[ok]) / np.maximum(1.0, np.abs(want[ok]))
        assert err.max(initial=0.0) <= PRIMITIVE_C, f"x = {x}: relative deviation {err.max():.3g}"


def _special_points(n: int) -> list[np.ndarray]:
    """-0, +0, NaN, +inf and -inf everywhere, and each in one place among random numbers."""
    rng = np.random.default_rng(n)
    points = [np.full(n, v) for v in (-0.0, 0.0, np.nan, np.inf, -np.inf)]
    for v in (-0.0, 0.0, np.nan, np.inf, -np.inf):
        for k in range(n):
            x = 1.5 * rng.normal(size=n)
            x[k] = v
            points.append(x)
    return points


# LAPACK's (SciPy's OpenBLAS, which XLA calls) choice of pivot in a column with a NaN: not reproduced
SPECIAL_EXCEPT = {("inv", "value")}


@pytest.mark.parametrize(("case", "form"), [(c, f) for c in sorted(CASES) for f in FORMS
                                            if (c, f) not in SLOW and (c, f) not in SPECIAL_EXCEPT])
def test_nan_infinities_and_signed_zeros_are_xlas(kernels, case, form):
    """At -0, +-inf and NaN, each case's value, Jacobian and Hessian by C are XLA's: NaN at the same places
    (a structural zero of a derivative times a NaN is NaN, as in XLA, unless XLA makes that product a select),
    the same infinities, zeros of the same signs where both are 0, and the other values to ``PRIMITIVE_C``."""
    lib, _, sizes, _ = kernels
    f, n, _ = CASES[case]
    fn = jax.jit(_form(f, form))
    for x in _special_points(n):
        want = np.asarray(fn(jnp.asarray(x)), np.float64).ravel()
        got = _call(lib, f"{case}_{form}", x, sizes[f"{case}_{form}"])
        where = f"{case} {form} at x = {x}\nC   {got}\nXLA {want}"
        assert np.array_equal(np.isnan(got), np.isnan(want)), f"NaN at other places: {where}"
        assert np.array_equal(got[np.isinf(want)], want[np.isinf(want)]), f"other infinities: {where}"
        zeros = (want == 0) & (got == 0)  # (an exact 0 may be 1e-17 in the other's rounding)
        assert np.array_equal(np.signbit(got[zeros]), np.signbit(want[zeros])), f"zeros of other signs: {where}"
        ok = np.isfinite(want)
        err = np.abs(got[ok] - want[ok]) / np.maximum(1.0, np.abs(want[ok]))
        assert err.max(initial=0.0) <= PRIMITIVE_C, f"relative deviation {err.max():.3g}: {where}"


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_case_holds_its_primitives_at_run_time(kernels, case):
    """The case is about what it says: its primitives are in the jaxprs (value, jacfwd, hessian) and listed in
    :data:`liemef.codegen.PRIMITIVES`."""
    _, _, _, prims = kernels
    held = set().union(*(prims[f"{case}_{form}"] for form in FORMS if (case, form) not in SLOW))
    assert CASES[case][2] <= held, f"{case}: {CASES[case][2] - held} not traced (got {sorted(held)})"
    assert CASES[case][2] <= codegen.PRIMITIVES


def test_nan_and_ties_follow_xla(kernels):
    """argmax takes the first NaN and the first of equal values, sort puts NaN last and -inf first and keeps
    ties in their order (as XLA). Out-of-range gathers (NaN) and an indefinite Cholesky (NaN) come at random
    inputs in the cases ``take_out_of_range`` and ``cholesky_indefinite``."""
    lib, _, sizes, _ = kernels
    cases = {"argmax_value": [1.0, np.nan, 3.0, np.nan], "argmin_value": [0.5, 0.5, -2.0, -2.0],
             "sort_value": [2.0, np.nan, -1.0, 0.0, -np.inf], "argsort_value": [1.0, 1.0, 0.0, 1.0]}
    for name, x in cases.items():
        f, _, _ = CASES[name.rsplit("_", 1)[0]]
        want = np.asarray(jax.jit(f)(jnp.asarray(x)), np.float64).ravel()
        np.testing.assert_array_equal(_call(lib, name, np.asarray(x), sizes[name]), want, err_msg=name)


def test_integer_division_follows_xla_where_c_has_no_result(kernels):
    """x / 0, x % 0 and INT32_MIN / -1 are undefined in C (the x86 division traps: the process died of SIGFPE);
    the translation gives XLA's -1, x, INT32_MIN and 0 there."""
    lib, _, sizes, _ = kernels
    f = CASES["int_div_rem"][0]
    for x in ([-2.0**31, 7.0, -1.0, 0.0], [5.0, -7.0, 0.0, 2.0], [-9.0, 2.0**31 - 1, 4.0, -1.0]):
        want = np.asarray(jax.jit(f)(jnp.asarray(x)), np.float64)
        np.testing.assert_array_equal(_call(lib, "int_div_rem_value", np.asarray(x), sizes["int_div_rem_value"]),
                                      want, err_msg=str(x))


@pytest.mark.parametrize("cc", COMPILERS)
def test_the_source_builds_warning_free(kernels, cc, tmp_path):
    """The source of every case compiles with GCC and Clang with the export's flags (-std=c99 -Wall -Wextra
    -Werror -pedantic) and no warning: GCC at -O1 (where its data-flow warnings run), Clang's front end (where
    all of its warnings are)."""
    compiler_or_skip(cc)
    _, source, _, _ = kernels
    proc = subprocess.run([cc, *warning_free_flags(cc, tmp_path / "k.o"), str(source)], capture_output=True,
                          text=True)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr[:4000]


@pytest.mark.parametrize(("exponent", "mantissa"), [(8, 7), (8, 23), (11, 23)])
def test_reduce_precision_below_float64_is_refused_not_ignored(exponent, mantissa):
    """At its own precision ``reduce_precision`` changes nothing (the case ``reduce_precision_own``); to a
    narrower format (bfloat16, float32) it rounds, which the translators have no C for: they raise, naming it
    (the engine then runs XLA), instead of passing the value through unrounded."""
    closed = jax.make_jaxpr(lambda x: jax.lax.reduce_precision(x * 1.2345678, exponent_bits=exponent,
                                                               mantissa_bits=mantissa))(jnp.zeros(3))
    for translate in (scalar_jaxpr_to_c, jaxpr_to_c):
        with pytest.raises(codegen.UnsupportedPrimitive, match=f"reduce_precision to {exponent} exponent and "
                                                               f"{mantissa} mantissa bits of a float64"):
            translate("f", closed, ["x"], ["o"])


def test_a_choice_by_values_is_not_taken_for_data_movement():
    """``select_and_gather_add`` (a max-pool's derivative: in each window, the tangent where the operand is
    largest) picks by the operand's values. Run on element ids as data movement, it picked by the ids, the last
    of each window: [20, 30, 40] here, where XLA gives [10, 30, 30]. It has no C, so the translators raise."""
    X = jnp.array([3.0, 1.0, 2.0, 0.5])
    pool = lambda v: jax.lax.reduce_window(v, -jnp.inf, jax.lax.max, (2,), (1,), "VALID")  # noqa: E731
    closed = jax.make_jaxpr(lambda t: jax.jvp(pool, (X,), (t,))[1])(jnp.zeros(4))
    assert "select_and_gather_add" in {e.primitive.name for e in closed.jaxpr.eqns}
    assert "select_and_gather_add" not in codegen.PRIMITIVES
    for translate in (scalar_jaxpr_to_c, jaxpr_to_c):
        with pytest.raises(codegen.UnsupportedPrimitive, match="select_and_gather_add"):
            translate("f", closed, ["x"], ["o"])


def test_array_backend_takes_at_run_time_as_xla(tmp_path):
    """The array translator (``export_c(backend="array")``) has run-time gathers along one axis only; there too
    an index out of range gives the fill value (NaN) of ``jnp.take``'s mode, as XLA, not a clamped element."""
    tr = Translator()
    texts, sizes = [], {}
    pairs = [("take_fill", "value"), ("take_fill", "jacfwd"), ("take_out_of_range", "value")]
    for case, form in pairs:
        f, n, _ = CASES[case]
        closed = jax.make_jaxpr(_form(f, form))(jnp.zeros(n))
        text, tr = jaxpr_to_c(f"{case}_{form}", closed, ["x"], ["o"], translator=tr)
        sizes[f"{case}_{form}"] = int(np.prod(closed.jaxpr.outvars[0].aval.shape, dtype=np.int64))
        texts.append(text + f"void call_{case}_{form}(const double *x, double *o);\n"
                     f"void call_{case}_{form}(const double *x, double *o) {{ {case}_{form}(x, o); }}\n")
    body = "\n".join(tr.function_texts + texts)
    tables = [ln for ln in tr.table_lines if re.search(rf"\b{ln.split()[3].split('[')[0]}\b", body)]  # as export_c
    code = "\n".join(tables) + "\n" + body
    (tmp_path / "a.c").write_text("#include <math.h>\n#include <stdint.h>\n" + helpers_used(code) + "\n" + code)
    proc = subprocess.run([codegen.compiler(), *FLAGS, "-shared", "-fPIC", "-o", str(tmp_path / "a.so"),
                           str(tmp_path / "a.c")], capture_output=True, text=True)
    assert proc.returncode == 0 and not proc.stderr, proc.stderr[:4000]
    lib = ctypes.CDLL(str(tmp_path / "a.so"))
    rng = np.random.default_rng(7)
    nan_seen = False
    for case, form in pairs:
        for _ in range(8):
            x = 1.5 * rng.normal(size=CASES[case][1])
            want = np.asarray(jax.jit(_form(CASES[case][0], form))(jnp.asarray(x)), np.float64).ravel()
            got = _call(lib, f"{case}_{form}", x, sizes[f"{case}_{form}"])
            np.testing.assert_allclose(got, want, rtol=PRIMITIVE_C, atol=PRIMITIVE_C, equal_nan=True)
            nan_seen |= bool(np.isnan(want).any())
    assert nan_seen  # some index was out of range
