"""`liemef --help` starts without JAX, the lazy package keeps its public surface, and float64 is on in every path.

The startup time itself is measured (``time liemef --help``), not asserted; these tests check its cause: which
modules the help and version paths import.
"""

import dataclasses
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest

import liemef
from liemef import cli
from liemef.codegen import BACKENDS
from liemef.connections import CARTAN_SCHOUTEN
from liemef.filters import ERROR_SIDES, INTERPOLATIONS, ORDERS, UPDATES
from liemef.studies import load, registry
from liemef.studies.compare import STUDIES
from liemef.studies.experiments import DEFAULT_BATCH_SIZE, EXPERIMENTS, SYSTEMS

HEAVY = ("jax", "jaxlib", "numpy", "matplotlib", "equinox", "liemef.studies.experiments", "liemef.reports.plots",
         "liemef._config")
COMMANDS = ("reproduce", "montecarlo", "run", "smooth", "export-c")
HELP_ARGS = (["--help"], ["-h"], ["--version"], ["reproduce", "--help"], ["run", "--help"],
             ["montecarlo", "--help"], ["export-c", "--help"])


def python(code: str) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter (no module of this process leaks into it)."""
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    return res


def test_importing_the_cli_imports_no_jax():
    res = python(f"""
        import sys
        import liemef.cli
        print(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib') or m in {HEAVY!r}))
    """)
    assert res.stdout.strip() == "[]"


def test_help_and_version_answer_without_jax():
    res = python(f"""
        import sys
        from liemef.cli import main
        for argv in {HELP_ARGS!r}:
            try:
                main(argv)
            except SystemExit as exit:
                assert exit.code in (0, None), (argv, exit.code)
            else:
                raise AssertionError(f"{{argv}}: no SystemExit")
        print("loaded:", sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib') or m in {HEAVY!r}))
    """)
    out = res.stdout
    assert out.rstrip().endswith("loaded: []"), out
    assert "liemef, version " + liemef.__version__ in out
    for command in COMMANDS:
        assert f"  {command} " in out
    for name, study in registry.STUDIES["experiment"].items():  # the reproduce help lists every experiment
        assert f"  {name:<14} {study.paper.split(',')[0]}" in out
    assert "[" + "|".join(sorted(registry.SYSTEMS)) + "]" in out  # run --system's choices


def _console_script() -> list[str]:
    script = Path(sysconfig.get_path("scripts")) / "liemef"
    return [str(script)] if script.is_file() else ["-c", "from liemef.cli import main; main()"]


def test_the_console_script_lists_the_commands_without_importing_jax():
    res = subprocess.run([sys.executable, "-X", "importtime", *_console_script(), "--help"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Usage: liemef [OPTIONS] COMMAND [ARGS]..." in res.stdout
    for command in COMMANDS:
        assert f"  {command} " in res.stdout
    imported = [line.rpartition("|")[2].strip() for line in res.stderr.splitlines() if line.startswith("import time:")]
    assert "liemef.cli" in imported
    assert not [m for m in imported if m.split(".")[0] in ("jax", "jaxlib") or m in HEAVY]


def test_the_registry_is_what_the_library_registers():
    """The JAX-free registry names and describes the studies and systems the library loads: the same names in
    the same order, the same titles and papers, and :func:`liemef.studies.load` of each the library's object."""
    experiments = registry.STUDIES["experiment"]
    assert list(experiments) == [name for name in EXPERIMENTS if name in experiments] == list(EXPERIMENTS)[:6]
    for name, study in experiments.items():
        assert (study.title, study.paper) == (EXPERIMENTS[name].title, EXPERIMENTS[name].paper)
        assert load("experiment", name) is EXPERIMENTS[name]
    comparisons = registry.STUDIES["comparison"]
    assert list(comparisons) == list(STUDIES)
    from liemef.studies.compare import _PARTS  # every comparison the library implements is declared, and no other

    assert sorted(_PARTS) == sorted(comparisons)
    for name, study in comparisons.items():
        assert load("comparison", name) is STUDIES[name] and study.title == STUDIES[name].description
        fields = {f.name for f in dataclasses.fields(STUDIES[name].settings)}
        assert set(study.settings) <= fields - {"seed", "runs", "filters"}, name  # --set's help names real keys
    assert sorted(registry.SYSTEMS) == sorted(SYSTEMS)
    for name, spec in SYSTEMS.items():  # each factory is the declared system of its name
        assert spec.name == name and callable(spec.make) and callable(spec.measured)
    assert SYSTEMS["attitude-velocity"].run_options == {"updates": "discrete", "curvature": "exact", "error": "left"}
    for moving in ("attitude-field", "attitude-position"):  # as compare broad runs them
        assert SYSTEMS[moving].run_options == SYSTEMS["attitude-velocity"].run_options
    assert all(not SYSTEMS[n].run_options for n in SYSTEMS
               if n not in ("attitude-velocity", "attitude-field", "attitude-position"))
    assert registry.DEFAULT_BATCH_SIZE == DEFAULT_BATCH_SIZE


def test_a_registered_experiment_must_agree_with_the_registry():
    from liemef.studies.experiments import register

    saved = dict(EXPERIMENTS)
    with pytest.raises(ValueError, match="already registered"):
        register(EXPERIMENTS["tse2"])
    try:
        del EXPERIMENTS["tse2"]
        with pytest.raises(ValueError, match="expected the registry's title and paper"):
            register(dataclasses.replace(saved["tse2-velocity"], name="tse2"))
    finally:
        EXPERIMENTS.clear()
        EXPERIMENTS.update(saved)


def test_the_choices_of_the_cli_are_the_registry():
    """Every choice of the command line is generated from the registry and the library's names: nothing to copy
    by hand when a study, a system or a connection is added."""
    params = {cmd: {p.name: p for p in cli.cli.commands[cmd].params}
              for cmd in (*COMMANDS, "compare", "schema", "dataset")}
    assert list(params["reproduce"]["experiment"].type.choices) == [*sorted(registry.names("experiment")), "all"]
    assert list(params["montecarlo"]["experiment"].type.choices) == sorted(EXPERIMENTS)
    assert list(params["compare"]["study"].type.choices) == list(STUDIES)
    for cmd in ("run", "export-c", "schema"):
        assert list(params[cmd]["system_name"].type.choices) == sorted(SYSTEMS)
    for cmd in ("reproduce", "run", "export-c"):
        assert list(params[cmd]["connection"].type.choices) == list(CARTAN_SCHOUTEN)
        assert list(params[cmd]["order"].type.choices) == list(ORDERS)
    assert list(params["run"]["interpolation"].type.choices) == list(INTERPOLATIONS)
    assert list(params["run"]["updates"].type.choices) == list(UPDATES)
    assert list(params["export-c"]["backend"].type.choices) == list(BACKENDS)
    for cmd in ("run", "export-c"):
        assert list(params[cmd]["error"].type.choices) == list(ERROR_SIDES)
    assert params["montecarlo"]["batch_size"].default == DEFAULT_BATCH_SIZE
    assert list(params["dataset"]["kind"].type.choices) == list(registry.DATASETS)


def test_the_lazy_package_keeps_its_public_surface():
    assert liemef.__all__ == ["MinimumEnergyFilter", "FilterState", "Trajectory", "Terms", "Connection",
                              "connection", "simulate", "SensorLog", "Truth", "smooth", "Smoothed", "groups",
                              "systems", "connections", "simulation", "metrics"]
    assert liemef.__version__ == "0.1.0"
    namespace: dict = {}
    exec("from liemef import *", namespace)  # noqa: S102
    assert set(liemef.__all__) <= set(namespace) and set(liemef.__all__) <= set(dir(liemef))
    assert namespace["MinimumEnergyFilter"].__module__ == "liemef.filters._mef"
    assert namespace["groups"] is sys.modules["liemef.groups"]
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        liemef.nope  # noqa: B018


@pytest.mark.parametrize("load", [
    "import liemef.groups",  # a submodule alone: liemef/__init__.py runs first but imports nothing
    "from liemef.groups import SO2",
    "from liemef import MinimumEnergyFilter",  # through the package's __getattr__
    "import liemef.studies.experiments._systems",
    "import jax; import liemef",  # JAX loaded first: float64 at once, as before
])
def test_float64_is_on_in_every_import_path(load):
    res = python(f"""
        {load}
        import jax
        import jax.numpy as jnp
        from liemef.groups import SO2
        print(jnp.ones(2).dtype, *{{leaf.dtype for leaf in jax.tree_util.tree_leaves(SO2.from_coords([0.3]))}})
    """)
    assert res.stdout.split() == ["float64", "float64"], res.stdout


def test_the_generated_schemas_are_the_systems():
    """liemef.studies._schemas (read without JAX by `run` and `schema`) is what the ready systems say; after a
    change, regenerate it with liemef.studies.logs.write_schemas()."""
    from liemef.studies import _schemas, logs

    assert sorted(_schemas.SCHEMAS) == sorted(registry.SYSTEMS)
    for name in registry.SYSTEMS:
        assert _schemas.SCHEMAS[name] == logs.system_schema(name), name


def test_a_bad_log_and_the_schema_are_answered_without_jax(tmp_path):
    """A log missing a column is exit 2 naming it, a wrong --x0 size exit 2, and `schema` prints the table, all
    before JAX is imported (the time is measured by benchmarks/bench_cli_errors.py, not asserted)."""
    log = tmp_path / "missing.csv"
    log.write_text("t,v_x,v_y,omega,gps_x\n0,1,0,0,0\n0.01,1,0,0,\n")
    good = tmp_path / "good.csv"
    good.write_text("t,v_x,v_y,omega,gps_x,gps_y\n0,1,0,0,0,0\n0.01,1,0,0,,\n")
    res = python(f"""
        import sys
        from liemef.cli import main
        for argv in ({["run", "--system", "localization", "--log", str(log), "--out", str(tmp_path / "o")]!r},
                     {["run", "--system", "localization", "--log", str(good), "--out", str(tmp_path / "o"),
                       "--x0", "1,2"]!r},
                     ["schema", "localization"]):
            try:
                main(argv)
            except SystemExit as exit:
                print("exit", exit.code)
        print("loaded:", sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib') or m in {HEAVY!r}))
    """)
    out = res.stdout + res.stderr
    assert out.count("exit 2") == 2 and "exit 0" in out, out
    assert "missing column(s) ['gps_y']" in out and "--x0" in out and "expected 3 finite numbers" in out
    assert "CSV header: t,v_x,v_y,omega,gps_x,gps_y" in out
    assert "loaded: ['numpy']" in res.stdout, out  # numpy reads the log; JAX is never imported
    assert not (tmp_path / "o").exists()


def test_the_compare_help_lists_the_registry_filters():
    """`liemef compare --help` lists the comparisons' filters from the registry, which declares exactly the
    filters the comparisons build."""
    from liemef.studies.compare._common import FILTERS

    assert list(FILTERS) == list(registry.FILTERS)
    text = cli.cli.commands["compare"].help
    for name, description in registry.FILTERS.items():
        assert f"  {name:<11} {description}" in text


def test_the_tune_choices_are_the_library_s():
    """`liemef tune`'s data, objectives and systems (declared in the JAX-free registry) are what
    liemef.studies.tune fits."""
    from liemef.studies import tune

    params = {p.name: p for p in cli.cli.commands["tune"].params}
    assert list(params["data"].type.choices) == list(registry.TUNE_DATA) == ["broad"]
    assert list(params["objective"].type.choices) == list(tune.OBJECTIVES) == list(registry.TUNE_OBJECTIVES)
    assert list(params["system_name"].type.choices) == list(tune.SYSTEMS) == list(registry.tune_systems()) == [
        "attitude-imu", "attitude-velocity", "attitude-position"]
    for name in registry.tune_systems():  # what a tuning file may set is tunable, with bounds; the defaults among it
        declared = registry.SYSTEMS[name]
        assert set(declared.tune_defaults) <= set(declared.tunable) <= set(tune.PARAMETERS), name


def test_each_dataset_s_systems_are_ready_ones_the_best_first():
    """`liemef dataset KIND --system`'s choices come from the one table of ready systems: every recording kind
    has its own, ranked without ties, the best model of its comparison first."""
    for kind in registry.DATASETS:
        ranked = registry.dataset_systems(kind)
        ranks = [r for s in ranked for k, r in registry.SYSTEMS[s].datasets if k == kind]
        assert ranked and len(set(ranks)) == len(ranks) and set(ranked) <= set(registry.SYSTEMS), kind
    assert registry.dataset_systems("broad") == ("attitude-velocity", "attitude-imu", "attitude-bias",
                                                 "attitude-field", "attitude-position")
    assert registry.dataset_systems("wifibot") == ("localization",)
    params = {p.name: p for p in cli.cli.commands["dataset"].params}
    assert sorted(params["system_name"].type.choices) == ["attitude-bias", "attitude-field", "attitude-imu",
                                                          "attitude-position", "attitude-velocity", "localization"]


def test_reproduce_all_refuses_config_options_before_jax(tmp_path):
    """studies.runs (what the commands call) loads without JAX, and `reproduce all` with a config option is
    bad input answered before JAX is imported."""
    res = python(f"""
        import sys
        from liemef.cli import main
        try:
            main(["reproduce", "all", "--out", {str(tmp_path / "o")!r}, "--seed", "3"])
        except SystemExit as exit:
            print("exit", exit.code)
        import liemef.studies.runs
        print("loaded:", sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib') or m in {HEAVY!r}
                                and m != "numpy"))
    """)
    assert "exit 2" in res.stdout and "loaded: []" in res.stdout, res.stdout + res.stderr  # numpy reads files
    assert "--seed: config options apply to one experiment" in res.stderr
    assert not (tmp_path / "o").exists()
