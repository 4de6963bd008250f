r"""The Chaplygin sleigh on SE(2) x R^2: Rigo, Sansonetto, Muradore 2023, Sec. 6, Tables 1-2, Figs. 3-6.

Printed in the paper (Sec. 6): J = 6.125, m = 125, a = 0.3, l = 0.2; inputs
$u_\omega = 10\sin(t/2)$, $u_v = \tfrac12\sin(t/5)$; T = 20 s; truth from $(\pi/6, 1, 2, 0, 0)$; the filter starts
at the true state; D = diag(0.4 x4, 0.2, 0.2) (GPS only: 0.4 I4), B2 = diag(10, 10), R = I, Q = I, alpha = 0;
K(0) = I5 for the (0)-connection and the constraint-preserving K(0) of eq. (63) for the (-)-connection; RK4 with
step Ts and a measurement every Ts, Ts = 10 ms (Table 1, Figs. 3-4) and 1 ms (Table 2, Figs. 5-6); GPS + INS and
GPS only. Errors $\delta\theta = \theta - \hat\theta$, ... (truth minus estimate).

Simulation choices the paper leaves open, and what reproduces its tables (``docs/chaplygin.md``, ``docs/errata.md``):

* ``weights``: ``"consistent"`` (default) is Theorem 4.1 with the stated Q = I, so that
  $D^{-\top} Q D^{-1}$ = diag(6.25 x4, 25, 25) weighs the residual (eq. (27)) *and* E. ``"printed"`` is the mix
  the paper prints: residual and Hessian part of E with the weights of eq. (27), the constant part of E as printed
  (2 l^2, 2, 2, 1, 1), which holds only for Q = D'D (:class:`PrintedWeightsFilter`). ``"unweighted"`` is
  Q = D'D throughout (what eqs. (33), (38), (48) presuppose): no weights at all.
* ``model_error_std``: the std of the unit-variance model error $\delta$ of eq. (18) in the truth, drawn per
  sample and held, entering as $B\delta$ = (0, B2 delta). 0 (default): the nominal truth. 1: the printed level,
  $B_2\delta$ of std 10 per sample (:data:`PRINTED_MODEL_ERROR_STD`).

:func:`trial` is the traceable core (one key, ``vmap``-able); :func:`run` one evaluated run;
:func:`reproduce` the whole study (``liemef reproduce chaplygin --runs N --out DIR``): the four configurations
(2 sensor sets x 2 connections) at Ts = 10 ms and 1 ms through :func:`~liemef.studies.experiments.montecarlo`,
Tables 1-2 side by side with the paper, the alternatives' numbers, and Figs. 3-6 from one representative run.

The package, one job per module: ``_paper`` (the config and the printed values), ``_trial`` (the filter as
printed, the setup cache, the run and the Monte Carlo trial) and ``_reproduce`` (the Monte Carlo grid and the
reproduction); this module registers :data:`CHAPLYGIN` from them. The tables and figures are written by
:mod:`liemef.reports.chaplygin`; its names are re-exported here.
"""

from ....reports.chaplygin import (
    CSV_HEADER,
    FIGURES,
    GREEK,
    LABEL,
    TABLE_UNITS,
    Entry,
    alternatives_markdown,
    band_fraction,
    figure,
    tables_markdown,
    velocity_markdown,
)
from ....systems.chaplygin import CONNECTIONS
from ... import registry
from .._base import Experiment, FigureSpec, register
from ._paper import (
    COMPONENTS,
    K0_CHOICES,
    PAPER_DTS,
    PAPER_TABLES,
    PRINTED_MODEL_ERROR_STD,
    SCALE,
    STATS3,
    WEIGHTS,
    ChaplyginConfig,
    paper_input,
    paper_value,
)
from ._reproduce import entries, figure_arrays, representative_trial, reproduce
from ._trial import (
    PrintedWeightsFilter,
    Setup,
    group_velocity,
    make_system,
    measured_state,
    run,
    setup,
    trial,
    trial_spec,
)

_POSE = ("theta", "x", "y")
_VEL = ("omega", "v")

CHAPLYGIN = register(Experiment(
    **registry.card("chaplygin"),
    default_config=ChaplyginConfig(),
    run_fn=run,
    trial_fn=trial_spec,
    figures=(
        FigureSpec("pose.png", _POSE, "Pose: nominal (black), measured (blue), filtered (green); errors (red)",
                   "Rigo et al. 2023, Figs. 3-6 (pose)"),
        FigureSpec("velocity.png", _VEL,
                   "Velocities: nominal (black), measured (blue), filtered (green); errors (red)",
                   "Rigo et al. 2023, Figs. 3-6 (velocities)"),
    ),
    tables=("Table 1 (Ts = 10 ms)", "Table 2 (Ts = 1 ms)"),
    runs=100,
    quick_config=ChaplyginConfig(table_dts=(0.01,), alternatives=False),
    quick_runs=8,
    reproduce_fn=reproduce,
))
"""``chaplygin``: one run of a :class:`ChaplyginConfig`; ``reproduce`` writes Tables 1-2 and Figs. 3-6."""

__all__ = ["CHAPLYGIN", "ChaplyginConfig", "CONNECTIONS", "WEIGHTS", "K0_CHOICES", "PRINTED_MODEL_ERROR_STD",
           "PAPER_DTS", "SCALE", "COMPONENTS", "STATS3", "PAPER_TABLES", "paper_input", "paper_value",
           "PrintedWeightsFilter", "Setup", "make_system", "setup", "trial", "group_velocity", "measured_state",
           "run", "trial_spec", "entries", "representative_trial", "figure_arrays", "reproduce", "Entry",
           "band_fraction", "tables_markdown", "velocity_markdown", "alternatives_markdown", "figure", "LABEL",
           "GREEK", "TABLE_UNITS", "FIGURES", "CSV_HEADER"]
