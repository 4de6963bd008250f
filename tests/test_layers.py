"""The layering contract: liemef's packages import one way, and no packages import each other in a cycle.

The layers, from the top: cli > studies > reports > metrics > smoothers > engines > codegen > filters > simulation >
systems > integrators, connections > groups > the private helpers (``[tool.importlinter]`` in
pyproject.toml, checked by import-linter). A lower layer never imports a higher one, not even inside a
function. Beside it, the import graph has no cycle, neither of modules nor collapsed to packages at any depth;
no module imports by name (``importlib``) but the package's root, the composition root that gives the filters the
engines above them (``liemef._runner``); and the layers above the filters read only their public contract.
"""

import ast
import itertools
from pathlib import Path

import grimp
import pytest
from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "liemef"


def test_import_linter_contract_is_kept():
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml")) == 0


def package_cycles(edges: set[tuple[str, str]], packages: set[str] | None = None) -> list[tuple[str, str]]:
    """Pairs of sibling packages that import each other, directly or through others, in a graph of module
    imports: each module is collapsed to its ancestor just below the two modules' common parent (where that
    ancestor is one of ``packages``, default: any)."""
    cycles = set()
    reach: dict[str, set[str]] = {}
    for a, b in edges:
        pa, pb = a.split("."), b.split(".")
        k = next((i for i, (x, y) in enumerate(zip(pa, pb, strict=False)) if x != y), min(len(pa), len(pb)))
        if k >= len(pa) or k >= len(pb):
            continue  # one contains the other (a package and its own module)
        if packages is not None and not {".".join(pa[:k + 1]), ".".join(pb[:k + 1])} <= packages:
            continue
        reach.setdefault(".".join(pa[:k + 1]), set()).add(".".join(pb[:k + 1]))
    for a, targets in reach.items():
        for b in targets:
            seen, todo = set(), [b]
            while todo:
                x = todo.pop()
                if x == a:
                    cycles.add(tuple(sorted((a, b))))
                    break
                if x not in seen:
                    seen.add(x)
                    todo.extend(reach.get(x, ()))
    return sorted(cycles)


def test_the_cycle_finder_finds_a_cycle():
    assert package_cycles({("p.a.x", "p.b.y"), ("p.b.z", "p.c.w"), ("p.c.v", "p.a.u")}) == [
        ("p.a", "p.b"), ("p.a", "p.c"), ("p.b", "p.c")]
    assert package_cycles({("p.a.x", "p.b.y"), ("p.b.z", "p.c.w")}) == []


def test_no_packages_import_each_other_in_a_cycle():
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    edges = {(a, b) for a in graph.modules for b in graph.find_modules_directly_imported_by(a)
             if b.startswith("liemef.") and not b.startswith(a + ".")}
    packages = {m for m in graph.modules if graph.find_children(m)}
    assert package_cycles(edges, packages) == []


def module_cycles(edges: set[tuple[str, str]]) -> list[list[str]]:
    """The import cycles of a graph of modules: its strongly connected components of more than one module
    (Tarjan's algorithm, iterative), each sorted, largest first."""
    adj: dict[str, list[str]] = {}
    for a, b in sorted(edges):
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in adj:
        if root in index:
            continue
        work = [(root, iter(adj[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, targets = work[-1]
            w = next(targets, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(adj[w])))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found, key=lambda c: (-len(c), c))


def test_the_module_cycle_finder_finds_cycles():
    edges = {("a", "b"), ("b", "c"), ("c", "a"), ("c", "d"), ("d", "e"), ("e", "d"), ("f", "a")}
    assert module_cycles(edges) == [["a", "b", "c"], ["d", "e"]]
    assert module_cycles({("a", "b"), ("b", "c"), ("a", "c")}) == []


def test_no_modules_import_each_other_in_a_cycle():
    """Not only packages: no two modules import each other, directly or through others, even inside a function
    (a module-level cycle is what a lazy import hides; a package's own ``__init__`` importing its modules is
    not one, since they never import the ``__init__`` back)."""
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    edges = {(a, b) for a in graph.modules for b in graph.find_modules_directly_imported_by(a)
             if b.startswith("liemef")}
    assert len(edges) > 400
    assert module_cycles(edges) == []


# Imports by name that the graph cannot see, each with the reason it does not break a layer.
BY_NAME = {
    ("liemef", "."): "the package's lazy attributes (PEP 562): the root is above every layer",
    ("liemef._jax", "jax._src"): "JAX's own internals, behind the one adapter (tests/test_jax_adapter.py)",
}


def _by_name_imports():
    for path in SRC.rglob("*.py"):
        mod = ".".join(path.relative_to(SRC.parent).with_suffix("").parts).removesuffix(".__init__")
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) in (
                    "import_module", "__import__"):
                yield mod, node


def test_every_import_by_name_is_accounted_for():
    found = set()
    for mod, node in _by_name_imports():
        if mod.startswith("liemef.cli"):
            continue  # the top layer may name anything
        found.add(mod)
        assert any(mod == m for m, _ in BY_NAME), f"{mod} imports by name at line {node.lineno}"
    assert found == {m for m, _ in BY_NAME}


@pytest.mark.parametrize("low, high", [("liemef.filters", "liemef.engines"), ("liemef.engines", "liemef.studies"),
                                       ("liemef.groups", "liemef.systems"), ("liemef.codegen", "liemef.engines")])
def test_a_lower_layer_imports_no_higher_one(low, high):
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    assert not graph.chain_exists(importer=low, imported=high, as_packages=True)


def test_only_the_reports_import_matplotlib():
    importers = set()
    for path in SRC.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            if any(n.split(".")[0] == "matplotlib" for n in names):
                importers.add(path.relative_to(SRC).parts[0])
    assert importers <= {"reports"}, importers


def test_layers_in_the_contract_are_the_packages_of_the_tree():
    import tomllib

    layers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]["layers"]
    named = {m.strip().removeprefix("liemef.") for layer in layers for m in layer.split("|")}
    present = {p.stem if p.is_file() else p.name for p in SRC.iterdir()
               if (p.suffix == ".py" and p.stem != "__init__") or (p.is_dir() and (p / "__init__.py").exists())}
    assert named == present, set(itertools.chain(named - present, present - named))


@pytest.mark.parametrize("low, high", [("liemef.reports", "liemef.studies"), ("liemef.metrics", "liemef.reports"),
                                       ("liemef.filters", "liemef.reports")])
def test_the_reports_sit_between_the_computing_and_the_studies(low, high):
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    assert not graph.chain_exists(importer=low, imported=high, as_packages=True)


def test_nothing_below_the_reports_loads_matplotlib():
    """Every module of the layers below the reports imports without loading matplotlib, even indirectly."""
    import subprocess
    import sys

    above = ("liemef.reports", "liemef.studies", "liemef.cli", "liemef.__main__")
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    below = sorted(m for m in graph.modules if m != "liemef" and not m.startswith(above))
    assert "liemef.filters" in below and "liemef.metrics" in below
    code = ("import importlib, sys\n"
            f"for m in {below!r}:\n    importlib.import_module(m)\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


BELOW_ENGINES = ("filters", "codegen", "simulation", "systems", "integrators", "connections", "groups")


def test_nothing_below_the_engines_names_them():
    """The filters reach the engines only through the slot the root fills (``liemef._runner``): no module of a
    layer below them names ``liemef.engines``, not even in a string, a comment or a docstring."""
    paths = [p for p in SRC.rglob("*.py") if p.relative_to(SRC).parts[0] in BELOW_ENGINES
             or (p.parent == SRC and p.stem.startswith("_") and p.stem != "__init__")]
    assert len(paths) > 50
    named = [str(p.relative_to(SRC)) for p in paths if "liemef.engines" in p.read_text()]
    assert named == []


@pytest.mark.parametrize("package", ["liemef.codegen", "liemef.engines", "liemef.smoothers"])
def test_no_module_outside_a_package_imports_its_private_modules(package):
    """The compiler, the engines and the smoothers are components: the rest of the package reads their public
    names (``liemef.codegen``'s: :func:`~liemef.codegen.kernel_for`, ...; the batch MAP of
    ``liemef.studies.optimum``: :func:`~liemef.smoothers.solve`), never a private module of theirs."""
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    depth = package.count(".") + 1
    private = {(a, b) for a in graph.modules if not a.startswith(package)
               for b in graph.find_modules_directly_imported_by(a)
               if b.startswith(package + ".") and any(part.startswith("_") for part in b.split(".")[depth:])}
    assert private == set()


def test_the_layers_above_read_only_the_filters_public_names():
    """No module outside ``liemef.filters`` imports a private module of it (``liemef.filters._base``, ...) or
    calls a private method of a filter: the filters' contract is their public names."""
    graph = grimp.build_graph("liemef", exclude_type_checking_imports=True)
    private = {(a, b) for a in graph.modules if not a.startswith("liemef.filters")
               for b in graph.find_modules_directly_imported_by(a)
               if b.startswith("liemef.filters.") and any(part.startswith("_") for part in b.split(".")[2:])}
    assert private == set()
    calls = []
    for path in SRC.rglob("*.py"):
        if path.relative_to(SRC).parts[0] != "filters":
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Attribute) and node.attr in PRIVATE_FILTER_METHODS:
                    calls.append(f"{path.relative_to(SRC)}:{node.lineno} .{node.attr}")
    assert calls == []


def _private_filter_methods() -> frozenset[str]:
    from liemef.filters import AbstractFilter, MinimumEnergyFilter

    return frozenset(name for cls in (AbstractFilter, MinimumEnergyFilter) for name in vars(cls)
                     if name.startswith("_") and not name.startswith("__"))


PRIVATE_FILTER_METHODS = _private_filter_methods()


def test_the_root_gives_the_filters_the_engines(monkeypatch):
    """The slot the filters call holds the engines the root gave (loaded once); an empty slot, or a provider
    that is not callable, is an error that says so."""
    import liemef
    import liemef.engines
    from liemef import _runner

    assert _runner.engines() is liemef.engines is _runner.engines()
    monkeypatch.setattr(_runner, "_PROVIDER", [])
    monkeypatch.setattr(_runner, "_LOADED", [])
    with pytest.raises(RuntimeError, match="no engines were given"):
        _runner.engines()
    with pytest.raises(ValueError, match="provider: expected a callable"):
        _runner.provide("liemef.engines")
    calls = []
    _runner.provide(lambda: calls.append(1) or liemef.engines)
    assert _runner.engines() is _runner.engines() is liemef.engines and calls == [1]
