"""The import graph of the whole tree: layers you can see in the folders, and no circles.

`bayesian_fields_core` is a stack of packages (LAYERS, top down). A module may import its own
package and any package below it, never one above; `params.py` and `errors.py` sit under
everything. The library never imports the service; the service (`services/`, installed as
`bayesian_fields_service`) may import the library, and its own packages are layered too.
Every import counts, at any depth of a module (a late import inside a function is as much an
arrow as one at the top), so the graph these tests read is the one the code runs.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = "bayesian_fields_core"
SERVICE = "bayesian_fields_service"
SOURCES = {LIBRARY: ROOT / "bayesian_fields_core", SERVICE: ROOT / "services"}

LAYERS: list[set[str]] = [
    {"cli"},
    {"eval"},
    {"viewer"},
    {"stages"},
    {"results"},
    {"objects"},
    {"job"},
    {"perception"},
    {"calibration"},
    {"fusion"},
    {"checks"},
    {"render"},
    {"scene"},
    {"geometry"},
    {"compute"},
    {"params", "errors", "__init__"},
]
"""The library's packages, top down. Members of one set share a floor and must not import each
other; a package may import itself and any floor below."""

SERVICE_LAYERS: list[set[str]] = [
    {"client", "admin"},
    {"api", "control"},
    {"worker"},
    {"jobs"},
    {"scenes"},
    {"webhooks", "live", "storage", "security", "sanitize"},
    {"records"},
    {"hooks"},
    {"observability"},
    {"config"},
    {"__init__"},
]
"""The service's packages, top down, as their imports stand: the control process sends stages
through the worker's Celery app and sits beside the API (neither imports the other); both and the
workers call the jobs domain (`jobs`: the job model and its rules, reaching the records and the
live state through its ports); below it the scenes domain (`scenes`: a job is submitted on a ready
scene, so the jobs side reads and share-locks scene rows through it, never the other way), which
reaches the rows through its records port and the bucket through `storage`; below them the
adapters, one job each and none importing another: the
callbacks (`webhooks`, which write their outbox rows through `records`), Redis and the broker
(`live`, the only package that knows either; the worker builds the Celery app and hands it in, so
`live` never imports `worker`), object storage (`storage`), API keys (`security`) and text safe to
serve (`sanitize`); then the records (the schema, every SQL statement and the unit of work), below
everything that reads or writes them; the hook points (`hooks.py`, called by routes and stages,
knowing nothing of who registers); `observability` (tracing and JSON log lines, which the
records' engine, the processes' starts, the dispatcher and the stages call, reading only the
settings); and `config` (`ServiceSettings`) at the bottom, because every
package reads settings and settings read nothing of the service. The operator's `admin` commands
(which start the control process) sit beside the user's client."""


def module_name(package: str, path: Path) -> str:
    parts = list(path.relative_to(SOURCES[package]).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([package, *parts])


def imported_modules(package: str, path: Path, modules: set[str] | None = None) -> set[str]:
    """Absolute names imported by `path` (relative imports resolved; `from a import b` adds a.b,
    and adds a too unless every imported name is a submodule in `modules`)."""
    module = module_name(package, path)
    base_package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = base_package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            submodules = {f"{target}.{a.name}" for a in node.names}
            names.update(submodules)
            if modules is None or not submodules <= modules:
                names.add(target)  # `from pkg import submodule` alone does not use pkg's own names
    return names


def all_modules() -> dict[str, Path]:
    return {
        module_name(package, path): path
        for package, folder in SOURCES.items()
        for path in sorted(folder.rglob("*.py"))
    }


def module_graph() -> dict[str, set[str]]:
    """Module -> the modules of this tree it imports (names that are not modules are dropped)."""
    modules = all_modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        package = name.split(".")[0]
        names = imported_modules(package, path, set(modules))
        graph[name] = {m for m in names if m in modules and m != name}
    return graph


def floor(module: str) -> tuple[str, int, str]:
    """(top package, floor index with 0 the top, the sub-package on that floor) of a module."""
    package, _, rest = module.partition(".")
    first = rest.split(".")[0] if rest else "__init__"
    layers = LAYERS if package == LIBRARY else SERVICE_LAYERS
    for index, members in enumerate(layers):
        if first in members:
            return package, index, first
    raise AssertionError(f"{module}: {first!r} is on no floor of {package}; add it to the layers")


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def climbing_arrows(graph: dict[str, set[str]]) -> dict[str, list[str]]:
    """Imports from a floor to a higher one, or sideways between two packages of one floor."""
    climbing: dict[str, list[str]] = defaultdict(list)
    for source, targets in graph.items():
        source_package, source_floor, source_sub = floor(source)
        for target in sorted(targets):
            target_package, target_floor, target_sub = floor(target)
            if target_package != source_package:
                continue  # library -> service is the next test's business
            if target_floor < source_floor or (target_floor == source_floor and target_sub != source_sub):
                climbing[source].append(target)
    return dict(climbing)


def test_every_package_has_a_floor() -> None:
    modules = all_modules()
    assert modules
    for module in modules:
        assert floor(module)[1] >= 0  # `floor` fails naming a package on no floor


@pytest.mark.slow
def test_no_import_circles() -> None:
    assert circles(module_graph()) == []


@pytest.mark.slow
def test_no_arrow_climbs_a_floor() -> None:
    assert climbing_arrows(module_graph()) == {}


@pytest.mark.slow
def test_the_library_never_imports_the_service() -> None:
    offenders = {
        source: sorted(t for t in targets if t.split(".")[0] in {SERVICE, "services"})
        for source, targets in module_graph().items()
        if source.startswith(LIBRARY)
    }
    assert {k: v for k, v in offenders.items() if v} == {}


@pytest.mark.slow
def test_no_generic_services_package_is_imported() -> None:
    for source, path in all_modules().items():
        names = imported_modules(source.split(".")[0], path)
        assert not any(m == "services" or m.startswith("services.") for m in names), source


@pytest.mark.slow
def test_the_checks_can_fail() -> None:
    """A late import inside a function is an arrow; a loop is a circle; an upward import climbs."""
    graph = module_graph()
    assert "bayesian_fields_core.objects.clustering" in graph["bayesian_fields_core.stages.cluster"]
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]
    upward = {
        "bayesian_fields_core.scene.ply": {"bayesian_fields_core.cli.main"},
        "bayesian_fields_core.cli.main": set(),
    }
    assert climbing_arrows(upward) == {"bayesian_fields_core.scene.ply": ["bayesian_fields_core.cli.main"]}
