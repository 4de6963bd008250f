r"""The Chaplygin sleigh study's config and the values Rigo et al. 2023 print (Sec. 6, Tables 1-2).

:class:`ChaplyginConfig` holds the paper's setup and the simulation choices it leaves open (package docstring);
:data:`PAPER_TABLES` and :func:`paper_value` the printed Tables 1-2, :func:`paper_input` the nominal input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .... import _validate
from ....metrics._stats import STATS
from ....systems.chaplygin import CONNECTIONS, SENSORS, STATE_NAMES, constraint_K0
from .._base import RunConfig

WEIGHTS = ("consistent", "printed", "unweighted")
K0_CHOICES = ("paper", "identity", "constrained")
PRINTED_MODEL_ERROR_STD = 1.0
"""The model error of eq. (18) at the printed level: delta ~ N(0, I2), so B2 delta has std b = 10 per sample."""
PAPER_DTS = (0.01, 0.001)
SCALE = 1e3
"""Errors are reported as the paper's tables do: mrad, mm, mrad/s, mm/s."""
COMPONENTS = STATE_NAMES
"""The errors the tables report, one per state coordinate (theta, x, y, omega, v)."""
STATS3 = STATS
"""The statistics the tables report: mean, std, rms over the run."""


def paper_input(t):
    r"""The nominal input of Rigo et al. 2023, Sec. 6: $(u_\omega, u_v) = (10\sin(t/2), \tfrac12\sin(t/5))$."""
    return jnp.stack([10.0 * jnp.sin(t / 2.0), 0.5 * jnp.sin(t / 5.0)])


def _table(rows: dict[str, tuple[tuple[float, float], ...]]) -> dict:
    """{component: ((mean0, mean-), (std0, std-), (rms0, rms-))} -> {connection: {component: (mean, std, rms)}}."""
    return {conn: {c: tuple(v[k] for v in rows[c]) for c in COMPONENTS} for k, conn in enumerate(CONNECTIONS)}


PAPER_TABLES: dict[tuple[float, str], dict[str, dict[str, tuple[float, float, float]]]] = {
    # Table 1, Ts = 10 ms; (0)-connection first, (-)-connection "in bracket" second. Units: mrad, mm, and (the
    # printed "mm/rad" misprints) mrad/s, mm/s.
    (0.01, "gps_ins"): _table({
        "theta": ((28.7, 71.1), (41.1, 32.7), (50.1, 78.2)),
        "x": ((-0.3, -37.8), (19.2, 122.6), (19.2, 128.3)),
        "y": ((-20.5, -281.0), (30.9, 177.6), (37.1, 332.3)),
        "omega": ((12.3, 12.3), (94.2, 94.2), (95.0, 95.0)),
        "v": ((4.9, 4.8), (99.4, 99.4), (99.5, 99.4)),
    }),
    (0.01, "gps"): _table({
        "theta": ((-2.1, -6.8), (180.5, 194.7), (180.4, 194.8)),
        "x": ((4.9, -13.8), (66.8, 77.9), (67.0, 79.1)),
        "y": ((-11.6, -51.9), (59.3, 103.2), (60.4, 115.5)),
        "omega": ((-2.5, 4.4), (208.8, 203.8), (208.8, 203.8)),
        "v": ((0.0, 15.4), (249.5, 251.9), (249.4, 252.3)),
    }),
    # Table 2, Ts = 1 ms
    (0.001, "gps_ins"): _table({
        "theta": ((-0.1, 4.9), (6.6, 9.2), (6.6, 10.4)),
        "x": ((8.3, -0.4), (9.5, 18.0), (12.6, 18.0)),
        "y": ((-6.1, -28.6), (7.3, 22.0), (9.5, 36.1)),
        "omega": ((1.5, 1.5), (31.2, 31.2), (31.2, 31.2)),
        "v": ((-1.8, -1.9), (33.9, 33.9), (33.9, 33.9)),
    }),
    (0.001, "gps"): _table({
        "theta": ((-6.1, -4.0), (44.4, 57.0), (44.8, 57.1)),
        "x": ((5.5, -8.8), (20.9, 31.9), (21.7, 33.1)),
        "y": ((-5.1, -33.5), (16.3, 36.6), (17.1, 49.6)),
        "omega": ((-1.1, -0.4), (54.2, 57.1), (54.2, 57.1)),
        "v": ((2.8, 1.0), (77.1, 80.0), (77.2, 80.0)),
    }),
}
"""Rigo et al. 2023, Tables 1-2: ``PAPER_TABLES[(Ts, sensor)][connection][component] = (mean, std, rms)`` in
mrad, mm, mrad/s, mm/s, of a single run each."""


def paper_value(dt: float, sensor: str, connection: str, component: str, stat: str) -> float | None:
    """The printed Table 1 (Ts = 10 ms) / Table 2 (1 ms) entry in mrad, mm, mrad/s, mm/s; None if not printed."""
    for (ts, sen), table in PAPER_TABLES.items():
        if math.isclose(ts, dt, rel_tol=1e-9) and sen == sensor and connection in table:
            return table[connection][component][STATS3.index(stat)]
    return None


@dataclass(frozen=True)
class ChaplyginConfig(RunConfig):
    r"""The Chaplygin sleigh experiment (Rigo et al. 2023, Sec. 6; docs/chaplygin.md).

    Fields:
        seed: the run's key is ``jax.random.key(seed)``; in :func:`reproduce` the Monte Carlo seed.
        sensor: ``"gps_ins"`` (two antennas + INS) or ``"gps"`` (antennas only, Remark 2).
        connection: ``"zero"`` (c = 1/2, Prop. 1) or ``"minus"`` (c = 0, Sec. 5).
        dt: Ts, the step of the truth and of the filter, one measurement per step (paper: 0.01 and 0.001).
        duration: final time T (paper: 20 s).
        order: ``"second"`` (the paper's filter) or ``"first"`` (the left-invariant EKF).
        integrator: ``"rkmk4"`` (the paper's RK4, on the group), ``"rkmk2"`` or ``"lie-euler"``, truth and
            filter.
        weights: ``"consistent"`` (default), ``"printed"`` or ``"unweighted"`` (module docstring).
        model_error_std: std of the unit-variance model error delta per sample in the truth (0: nominal truth;
            :data:`PRINTED_MODEL_ERROR_STD` = 1: the printed level, B2 delta of std 10).
        K0: ``"paper"`` (I5 for ``"zero"``, eq. (63) for ``"minus"``), ``"identity"`` or ``"constrained"``
            (eq. (63): I5 with the third row and column zeroed).
        alpha: forgetting factor (paper: 0).
        truth0, filter0: initial truth and estimate (theta, x, y, omega, v); the paper starts the filter at the
            true state.
        table_dts, alternatives: :func:`reproduce` only: the Ts of the tables it writes, and whether it also runs
            the alternative simulation choices (printed weights, printed model error, unweighted).
    """

    seed: int = 0
    sensor: str = "gps_ins"
    connection: str = "zero"
    dt: float = 0.01
    duration: float = 20.0
    order: str = "second"
    integrator: str = "rkmk4"
    weights: str = "consistent"
    model_error_std: float = 0.0
    K0: str = "paper"
    alpha: float = 0.0
    truth0: tuple[float, ...] = (math.pi / 6, 1.0, 2.0, 0.0, 0.0)
    filter0: tuple[float, ...] = (math.pi / 6, 1.0, 2.0, 0.0, 0.0)
    table_dts: tuple[float, ...] = PAPER_DTS
    alternatives: bool = True

    def __post_init__(self):
        self._check_run()
        _validate.choice("sensor", self.sensor, set(SENSORS))
        _validate.choice("connection", self.connection, set(CONNECTIONS))
        _validate.choice("weights", self.weights, set(WEIGHTS))
        _validate.choice("K0", self.K0, set(K0_CHOICES))
        _validate.nonnegative("alpha", self.alpha)
        _validate.nonnegative("model_error_std", self.model_error_std)
        _validate.array("truth0", self.truth0, (5,))
        _validate.array("filter0", self.filter0, (5,))
        dts = _validate.array("table_dts", self.table_dts, (None,))
        if dts.size == 0 or not np.all(dts > 0):
            raise ValueError(f"table_dts: expected one or more steps > 0, got {self.table_dts}")
        if not isinstance(self.alternatives, bool):
            raise ValueError(f"alternatives: expected True or False, got {self.alternatives!r}")
        self._freeze(floats=("alpha", "model_error_std"),
                     tuples=("truth0", "filter0", "table_dts"))

    @property
    def K0_matrix(self) -> np.ndarray:
        """The initial gain: I5, or eq. (63) (``K0="constrained"``, or ``"paper"`` with the (-)-connection)."""
        constrained = self.K0 == "constrained" or (self.K0 == "paper" and self.connection == "minus")
        return constraint_K0() if constrained else np.eye(5)
