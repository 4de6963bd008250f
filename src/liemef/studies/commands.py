"""The commands of ``liemef``, as data: each command's help and its arguments and options, declared once.

:mod:`liemef.cli` builds its click commands from :data:`COMMANDS` (one small function turns a :class:`Param` into
a click argument or option) and only parses, calls the library and prints. The choices and lists here come from
:mod:`liemef.studies.registry` and :mod:`liemef._names`; like them, this module loads without JAX (and without
click), so that ``liemef --help`` answers at once.

A parameter's ``type`` is ``None`` (text), ``int``, ``float``, :data:`PATH` (a path), ``("choice", names)``
or ``("at least", n)`` (an integer >= n).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .. import _names
from . import registry

PATH = "path"
"""The ``type`` of a parameter that is a file or folder."""
PROGRESS = "--progress/--no-progress"
"""The progress switch, on by default: on stderr, drawn in place on a terminal and a line at a time in logs and
pipes (a long command piped into a file still says how far it is); ``--no-progress`` is quiet."""


@dataclass(frozen=True)
class Param:
    """One argument (``argument=True``) or option of a command: its click declarations (``decls``), its
    ``type`` (see the module's text) and the rest of its click attributes (``attrs``: help, default, ...)."""

    decls: tuple[str, ...]
    type: Any = None
    argument: bool = False
    attrs: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Command:
    """A command: its ``help`` and its ``params`` in the order ``--help`` lists them."""

    help: str
    params: tuple[Param, ...] = ()


def option(*decls: str, type: Any = None, **attrs) -> Param:
    """An option of a command (``attrs`` as click's: help, default, show_default, required, ...)."""
    return Param(decls, type, False, attrs)


def argument(*decls: str, type: Any = None, **attrs) -> Param:
    """An argument of a command."""
    return Param(decls, type, True, attrs)


def progress(text: str) -> Param:
    """``--progress/--no-progress``, on by default (:data:`PROGRESS`)."""
    return option(PROGRESS, default=True, show_default=True,
                  help=text + " In place on a terminal, a line at a time when piped.")


def choice(names) -> tuple:
    """The ``type`` of a parameter that takes one of ``names``."""
    return ("choice", tuple(names))


def at_least(n: int) -> tuple:
    """The ``type`` of an integer parameter >= ``n``."""
    return ("at least", n)


EXPERIMENTS = tuple(sorted(registry.names("experiment")))
COMPARISONS = registry.names("comparison")
SYSTEMS = tuple(sorted(registry.SYSTEMS))

FORCE = option("--force", is_flag=True, help="Replace --out even if it holds files of another command.")
SETTINGS = option("--set", "settings", multiple=True, metavar="KEY=VALUE",
                  help="Override any config field (repeatable), e.g. --set dt=0.01 --set alpha=0.1.")
OUT = option("--out", required=True, type=PATH, help="Output folder (created if missing).")
CONNECTION = option("--connection", type=choice(_names.CONNECTIONS), default="zero", show_default=True)
ORDER = option("--order", type=choice(_names.ORDERS), default="second", show_default=True)
ALPHA = option("--alpha", type=float, default=0.0, show_default=True, help="Forgetting factor.")
SUBSTEPS = option("--substeps", default="auto", show_default=True,
                  help="Integrator steps per sample interval: auto (by stiffness) or a number.")
INTEGRATOR = option("--integrator", type=choice(_names.INTEGRATORS), default="rkmk4", show_default=True,
                    help="The filter's Lie-group integrator, each sub-step: rkmk4 (order 4), rkmk2 (order 2: two "
                    "evaluations of the filter's field instead of four, always cheaper, as accurate where sub-steps "
                    "are short, as on a high-rate IMU) or lie-euler (order 1; on fast motion K can lose positive "
                    "definiteness, a failed run). A tuning file records the tune's; `liemef run --params` warns when "
                    "the run's is not the file's.")
SYSTEM_FILE = option("--system-file", type=PATH, help="A Python file that defines `system`.")
TIMEOUT = option("--timeout", type=float, default=registry.SYSTEM_FILE_TIMEOUT, show_default=True,
                 help="Seconds --system-file may take to load before it is stopped (0: no limit).")
ERROR = option("--error", type=choice(_names.ERROR_SIDES), default="auto", show_default=True,
               help="The error coordinates of the filter: auto (the right error where a sensor sees the world from "
               "the body, a landmark or a field's direction, and none is a position fix; else the left), left "
               "(Theorem 4.1's) or right. K is written as the left error's covariance either way.")


def _run_defaults(key: str) -> str:
    """The ready systems that run with their own value of the filter option ``key``, as "NAME: VALUE" (read
    without JAX from :data:`liemef.studies.registry.SYSTEMS`)."""
    return ", ".join(f"{name}: {dict(s.run_options)[key]}" for name, s in registry.SYSTEMS.items()
                     if key in dict(s.run_options))


def system(text: str) -> Param:
    """``--system NAME``, a ready system, with the help ``text``."""
    return option("--system", "system_name", type=choice(SYSTEMS), help=text)


CLI = Command("""Second-order-optimal minimum-energy filtering on matrix Lie groups.

    Exit status: 0 ok, 1 a failed run (or no usable trial, or a full disk), 2 bad input, 3 a run whose
    innovations are inconsistent with its K, 4 one whose linearization the monitor calls nonlinear, 5 a
    smoother that did not converge (3-5: `run` and `smooth`, their outputs written whole), 130 interrupted.""")

REPRODUCE = Command(
    "Run a paper EXPERIMENT and write metrics.json, arrays.npz, its figures and error tables to --out, then print "
    "the error table; with --runs N (or the experiment's default) also a Monte Carlo of N seeded trials "
    "(montecarlo.md/.csv/.json/.npz).\n\n`reproduce all --out DIR` runs every experiment at a reduced size (--quick, "
    "the default) or at the papers' size (--full), one folder each, and writes DIR/index.md. `reproduce --list` "
    "lists the experiments with their papers, figures and tables.\n\n\b\nExperiments:\n"
    + "\n".join(f"  {s.name:<14} {s.paper}" for s in registry.STUDIES["experiment"].values()), (
        argument("experiment", required=False, type=choice([*EXPERIMENTS, "all"]), metavar="EXPERIMENT|all"),
        option("--list", "list_", is_flag=True, help="List the experiments (paper, figures, tables) and exit."),
        option("--out", type=PATH, help="Output folder (created if missing)."),
        option("--quick/--full", default=None, help="The experiment's reduced laptop size, or the paper's (default: "
               "--full for one experiment, --quick for all)."),
        option("--runs", type=at_least(0), help="Monte Carlo trials (default: the experiment's; 0: the seeded run "
               "only)."),
        option("--seed", type=int, help="Random seed (default: the experiment's, 0)."),
        option("--duration", type=float, help="Final time T in seconds (default: the paper's)."),
        option("--connection", type=choice(_names.CONNECTIONS), help="Cartan-Schouten connection (default: zero)."),
        option("--order", type=choice(_names.ORDERS), help="second: the paper filter; first: the left-invariant "
               "EKF."),
        SETTINGS, FORCE, progress("Monte Carlo progress on stderr.")))

MONTECARLO = Command(
    """Run N seeded trials of EXPERIMENT, batched with vmap, and print the statistics: per trial the mean, std
    and rms over time of each error component, then across trials their mean, spread and percentiles. Exit
    status 1 when no trial is usable (every one diverged): then --out holds failure.json alone.""", (
        argument("experiment", type=choice(EXPERIMENTS), metavar="EXPERIMENT"),
        option("--runs", type=at_least(1), default=100, show_default=True, help="Number of trials."),
        option("--seed", type=int, default=0, show_default=True,
               help="Trial i uses jax.random.split(jax.random.key(seed), runs)[i]."),
        option("--batch-size", type=at_least(1), default=registry.DEFAULT_BATCH_SIZE, show_default=True,
               help="Trials per compiled vmap batch (the results do not depend on it)."),
        option("--out", type=PATH, help="Write montecarlo.npz/.json/.md/.csv to this folder (created if missing)."),
        option("--duration", type=float,
               help=f"Final time T in seconds (default: the paper's); {registry.DURATION_RULE}."),
        option("--quick", is_flag=True, help="Start from the experiment's reduced config."),
        SETTINGS, FORCE, progress("Trials done, elapsed time and ETA on stderr.")))

RUN = Command(
    """Filter a recorded log with a ready system or your own, and write the estimates, K's diagonal and the
    innovations to --out. A failed run (non-finite, K no longer symmetric or positive definite, a gate) writes
    only failure.json, says where, when and why, and exits with status 1. A run whose innovations are
    inconsistent with K (the innovation monitor, metrics.json's "innovations") writes all its outputs, says which
    sensor and when, and exits with status 3; one whose innovations are consistent but whose outputs are so curved
    over K's spread that K may understate the errors where no sensor looks (the monitor's "nonlinear") does the
    same with status 4.""", (
        system("A ready system the log was recorded with (or --system-file)."),
        option("--system-file", type=PATH, help="A Python file that defines `system` (your own liemef system) and "
               "optionally K0, x0, initial_guess(y0)."), TIMEOUT,
        option("--log", "log_path", required=True, type=PATH,
               help="Recorded log: CSV with the system's columns (`liemef schema SYSTEM`; an empty field is a "
                    "missing sample), NPZ with ts, us, ys (or one time vector per sensor), or a ROS bag (a .bag "
                    "file, or a ROS 2 bag folder with its metadata.yaml) with --topics."),
        option("--topics", type=PATH, help="With a ROS 1 .bag or a ROS 2 bag folder as --log: the JSON/TOML "
               "mapping from topics to the system's columns (liemef.reports.rosbag)."),
        option("--tum/--no-tum", default=False, help="Also write the estimates as a TUM trajectory, estimates.tum."),
        OUT,
        option("--x0", help="Initial estimate in coordinates, comma separated (default: the system file's x0, "
               "else read off the first present measurements)."),
        option("--k0", type=float, help="Initial gain K(0) = k0 * I (default: the system file's K0, else 1)."),
        option("--k0-diag", help="Initial gain K(0) = diag(...), comma separated (overrides --k0)."),
        CONNECTION, ORDER, ALPHA,
        option("--interpolation", type=choice(_names.INTERPOLATIONS), default="hold", show_default=True,
               help="Inputs and dense measurements held over each interval, or linear between samples."),
        option("--updates", type=choice(_names.UPDATES),
               help="Sample sensors: held over the interval after their time stamp (the papers' scheme), or used "
               "at their own time (the hybrid filter: recommended for sample sensors). Default: hold, or the "
               f"ready system's ({_run_defaults('updates')})."),
        option("--curvature", type=choice(("safe", "exact")),
               help="The outputs' second-order term: safe (kept where it lowers the Gauss-Newton information, never "
               "below zero; dropped elsewhere) or exact (Theorem 4.1's, the papers' filter). Default: safe, or the "
               f"ready system's ({_run_defaults('curvature')})."),
        option("--error", type=choice(_names.ERROR_SIDES), help=ERROR.attrs["help"] + " Default: auto, or the ready "
               f"system's ({_run_defaults('error')})."), SUBSTEPS,
        INTEGRATOR,
        option("--gap", type=float, help="An interval longer than this (s) is a gap: predicted through, dense "
               "measurements not held (default: 10 x the median interval)."),
        option("--chunk", type=at_least(16), default=65536, show_default=True,
               help="Samples per compiled chunk (progress is shown between chunks)."),
        option("--params", "params_file", type=PATH,
               help="A tuning file of `liemef tune` (JSON) for --system " + " or ".join(registry.tune_systems())
                    + " (the file's system): its final parameter set (recorded in metrics.json with its SHA-256; "
                      "docs/imu.md)."),
        option("--set", "settings", multiple=True, metavar="KEY=VALUE",
               help="A parameter of the ready system's factory (repeatable), e.g. --set gnss_std=0.5 --set "
                    "biases=true for inertial-navigation; recorded in metrics.json (config.system_settings)."),
        option("--monitor/--no-monitor", default=True, show_default=True,
               help="Test the innovations against K (chi-square windows per sensor; exit status 3 where they are "
               "inconsistent) and the outputs' linearization over K's spread (exit status 4 where it is "
               "nonlinear)."),
        FORCE, progress("Samples filtered, on stderr, between chunks.")))

SMOOTH = Command(
    """Smooth a recorded log: filter it as `liemef run` does (the same options), then estimate every state from
    all the samples, before and after it, by minimizing the filter's own cost over the whole log (liemef.smooth,
    docs/smoothing.md). Writes the same files as `liemef run`, with the smoother's estimates, the diagonal of
    their marginal covariances and the residuals at them; metrics.json's "smoother" says how it converged, and
    "innovations" keeps the filter's innovation monitor. A failed filter or smoother writes only failure.json and
    exits with status 1; a smoother that does not converge writes its outputs, says so and exits with status 5;
    statuses 3 and 4 are the filter's innovation monitor's, as in `liemef run`.""",
    RUN.params[:-2] + (
        option("--max-iterations", type=at_least(1), default=200, show_default=True,
               help="The most Levenberg-Marquardt steps of the smoother."),
        option("--tol", type=float, default=1e-9, show_default=True,
               help="The smoother has converged when an accepted step's largest component is below this."),
        option("--smooth-chunk", type=at_least(1),
               help="Smooth in windows that each estimate this many states, for a log too long to smooth as one "
               "problem: the memory is one window's, and the estimate approaches the whole log's as the overlap "
               "grows (docs/smoothing.md, Long logs). Default: the whole log as one problem."),
        option("--smooth-overlap", type=at_least(0),
               help="With --smooth-chunk: the samples each window adds before and after its states (default: half "
               "of --smooth-chunk)."),
    ) + RUN.params[-2:-1] + (progress("Samples filtered, on stderr, between chunks (the filter's pass)."),))

EXPORT_C = Command(
    """Write the filter of a ready system (--system) or of your own (--system-file) as standalone C99: NAME.h
    and NAME.c in --out, with NAME_init, NAME_step (one sample interval, exactly as the filter's step), NAME_run
    and the coordinate maps. No heap, no library but libm; the weights, connection and parameters are constants
    of the source (export again for new ones). The two files are written in place, each whole or not at all
    (the folder may be your project's). See docs/export-c.md.""", (
        system("A ready system (or --system-file)."), SYSTEM_FILE, TIMEOUT,
        option("--out", required=True, type=PATH, help="Folder for NAME.h and NAME.c (created if missing; a "
                                                        "failed export leaves no folder it created)."),
        option("--name", help="The C prefix of every exported name, a C identifier (default: the system's name with "
                              "- replaced by _)."),
        CONNECTION, ORDER, ERROR,
        option("--integrator", type=choice(_names.EXPORT_INTEGRATORS), default="rkmk4", show_default=True),
        ALPHA, SUBSTEPS,
        option("--max-substeps", type=at_least(1), default=256, show_default=True,
               help="The most steps 'auto' takes in one interval."),
        option("--backend", type=choice(_names.C_BACKENDS), default="auto", show_default=True,
               help="scalar: straight-line code (fast, its size grows as n^3); array: loops over arrays (compact); "
                    "auto: scalar up to n = 12.")))

SCHEMA_COMMAND = Command(
    """Print the log columns of SYSTEM (a ready system) or of --system-file: names, units, roles and the
    sensors' noise levels, and the CSV header that `liemef run` expects.""", (
        argument("system_name", required=False, type=choice(SYSTEMS), metavar="SYSTEM"), SYSTEM_FILE, TIMEOUT))

DATASET = Command(
    """Convert a real recording (read in place, e.g. from ../shared/realdata) into a liemef log for
    `liemef run`, and print the command that filters it: `broad FILE.mat` (BROAD IMU trial; by default the log
    of the bounded-velocity model attitude-velocity, the best of `liemef compare broad`; --system
    attitude-position, attitude-imu, attitude-bias or attitude-field for the others) or `wifibot FILE.txt`
    (wheel odometry input with synthetic 1 Hz GPS, system localization). PATH may also be the id of a
    recording present in the real-data folder (`broad 16`, `wifibot 4`; found by reading the files).""", (
        argument("kind", type=choice(registry.DATASETS)), argument("path", type=PATH),
        option("--out", required=True, type=PATH,
               help="The log to write (.csv, or .npz), in the columns of the matching ready system."),
        option("--truth", type=PATH, help="Also write the ground truth here (CSV)."),
        option("--seconds", type=float, help="Only the first SECONDS (> 0) of the recording, at least two samples."),
        option("--gps-std", type=float, default=0.1, show_default=True,
               help="wifibot: std (m) of the synthetic 1 Hz GPS (ground truth + noise, numpy seed 0)."),
        option("--system", "system_name", type=choice(sorted({s for k in registry.DATASETS
                                                               for s in registry.dataset_systems(k)})),
               help="The ready system whose log to write: " + "; ".join(
                   f"{k}: {', '.join(v)} (default {v[0]})" for k, v in
                   ((k, registry.dataset_systems(k)) for k in registry.DATASETS)) + "."),
        option("--norms", is_flag=True, help="broad: the log of attitude-imu (the same as --system attitude-imu).")))

TUNE = Command(
    """Fit an IMU model's noise levels (--system) to the BROAD trials present, by a derivative-free
    search, with nested leave-one-trial-out cross-validation (each fold's search never sees its trial); writes
    the held-out, training and final set's errors and the tuned set (tune.json, accepted by `liemef run
    --params` and `liemef compare broad --set params=...`).""", (
        argument("data", type=choice(registry.TUNE_DATA)),
        option("--out", required=True, type=PATH,
               help="Output folder: tune.json (the tuned set, for run/compare --set params=...) and tune.md."),
        option("--objective", type=choice(registry.TUNE_OBJECTIVES), default="truth", show_default=True,
               help="; ".join(f"{k}: {v}" for k, v in registry.TUNE_OBJECTIVES.items()) + "."),
        option("--trials", metavar="A,B,...", help="BROAD trial ids (default: every trial present)."),
        option("--params", "names", metavar="A,B,...", help="Parameters to tune (default: liemef.studies.tune's)."),
        option("--seconds", type=float, default=90.0, show_default=True,
               help="Tune on a window of each trial: 5 s before the end of the rest found in the IMU, then SECONDS "
                    "of motion (0: whole trials); evaluate with `compare broad`."),
        option("--start", metavar="A=X,B=Y,...",
               help="Starting values of every search (default: the model's defaults, which for attitude-velocity "
                    "and attitude-position were tuned on the shared trials: start elsewhere for an honest "
                    "held-out error)."),
        option("--maxfev", type=at_least(1), default=40, show_default=True,
               help="Points of the final search (each runs every trial), and of each fold's unless --fold-maxfev."),
        option("--fold-maxfev", type=at_least(1),
               help="Points of each leave-one-out fold's own search, on the other trials only (default: --maxfev, "
                    "the final search's procedure). The tune runs about (trials + 1) searches."),
        option("--system", "system_name", type=choice(registry.tune_systems()), default="attitude-imu",
               show_default=True, help="The model: " + " or ".join(f"{k} ({registry.SYSTEMS[k].tune})" for k in
                                                                   registry.tune_systems()) + "."),
        option("--updates", type=choice(_names.UPDATES), default="hold", show_default=True,
               help="discrete: samples at their own time (the hybrid update, gyro sample k over the interval "
                    "ending at t_k), as compare broad's mef-imu-d."),
        INTEGRATOR,
        option("--realdata", type=PATH, help="The real-data folder (default: found)."),
        option("--workers", type=at_least(1),
               help="Threads that run a point's trials side by side (default: the CPUs this process may use)."),
        FORCE, progress("A progress bar on stderr.")))

COMPARE = Command(
    "Compare the minimum-energy filter with the filters people use on STUDY, on the same trials.\n\n"
    "\b\nFilters (--filters; each study's default set is in its tables):\n"
    + "\n".join(f"  {name:<11} {description}" for name, description in registry.FILTERS.items()) + "\n\n"
    + "\n\n".join(f"{s.name}: {s.help}" for s in registry.STUDIES["comparison"].values())
    + "\n\nTrials where a filter fails are counted and named, and left out of the statistics; so is a BROAD trial "
    "with no scored sample (a slice that ends before its movement). Exit status 1 when no trial of any filter is "
    "usable.", (
        argument("study", type=choice(COMPARISONS)), OUT,
        option("--runs", type=at_least(1), help="Trials (the same for every filter; default: the study's)."),
        option("--seed", type=at_least(0), default=0, show_default=True,
               help="First seed: trial i uses split(key(seed), runs)[i] (localization with --set rng=numpy: "
                    "ukfm's stream seeded seed + i, as inertial-navigation; wifibot: the GPS noise of seed + i)."),
        option("--filters", metavar="A,B,...", help="Filters to compare (default: all of the study's)."),
        option("--set", "settings", multiple=True, metavar="KEY=VALUE",
               help="Any other setting of the study (repeatable). " + " ".join(
                   f"{s.name}: {', '.join(s.settings)}." for s in registry.STUDIES["comparison"].values())),
        FORCE, progress("One line per filter.")))

CAMPAIGN = Command(
    """Monte Carlo campaigns over a grid of settings on Dask: resumable, fault-tolerant.

    A campaign file (TOML or YAML) names an experiment (or an experiment file), a grid of config values, the
    seeds per setting and an output folder; see `liemef campaign run --help` and docs/campaigns.md.""")

CAMPAIGN_FILE = argument("file", type=PATH, metavar="FILE")
CAMPAIGN_OUT = option("--out", type=PATH, help="Output folder (default: the file's `out`).")

CAMPAIGN_RUN = Command(
    """Run the campaign FILE, or resume it: tasks already in its output folder are not computed again.

    Each setting's trials run as tasks of whole compiled vmap batches on Dask; each result is written to the
    output folder as it arrives (tasks/, manifest.jsonl with a SHA-256 per task). When all are finished:
    settings/*/montecarlo.{npz,json,md,csv}, summary.md, summary.csv and result.json. Trial i of a setting
    uses the key of `liemef montecarlo` trial i, so the statistics are the same. Exit status: 0 when complete,
    1 on an error (the failed task is named; finished tasks are kept), 130 when interrupted (Ctrl-C or
    SIGTERM): run the same command again to resume.""", (
        CAMPAIGN_FILE, CAMPAIGN_OUT,
        option("--scheduler", metavar="tcp://HOST:PORT",
               help="Use this running Dask scheduler and its workers, as given (tls://HOST:PORT: with the "
                    "credentials of Dask's configuration; docs/campaigns.md). Default: a local cluster that "
                    "admits only this run (TLS with credentials made for it, on 127.0.0.1, no dashboard)."),
        option("--workers", type=at_least(1), default=2, show_default=True,
               help="Worker processes of the local cluster (one thread each)."),
        progress("Tasks done, trial-steps/s and time left on stderr.")))

CAMPAIGN_STATUS = Command(
    """How far the campaign FILE has come: finished tasks per setting (verified against their checksums),
    and whether its results are complete. Runs nothing.""", (CAMPAIGN_FILE, CAMPAIGN_OUT))

COMMANDS: dict[str, Command] = {
    "liemef": CLI, "reproduce": REPRODUCE, "montecarlo": MONTECARLO, "run": RUN, "smooth": SMOOTH,
    "export-c": EXPORT_C,
    "schema": SCHEMA_COMMAND, "dataset": DATASET, "tune": TUNE, "compare": COMPARE, "campaign": CAMPAIGN,
    "campaign run": CAMPAIGN_RUN, "campaign status": CAMPAIGN_STATUS}
"""Every command of ``liemef`` by its name (a subcommand as ``"campaign run"``)."""
