"""Routes translate HTTP and call a domain (issue 43 item 3): `AppState` exposes the domains, the
settings and the key ring (and the process's own parts), never a bucket, a Redis client or a
records engine; and no route imports the records, Redis or SQLAlchemy, or reaches for an
object's ``.database``, ``.redis`` or ``.store``.

Both checks read the real code (the dataclass's resolved field types; each route module's syntax
tree), and each has a probe that shows it fails on what it guards against.
"""

from __future__ import annotations

import ast
import dataclasses
import types
import typing
from pathlib import Path

import redis
from sqlalchemy import Connection, Engine

from bayesian_fields_core.job.store import PrefixedStore, Store
from bayesian_fields_service.api.state import AppState

ROUTES = Path(__file__).resolve().parents[3] / "services" / "api" / "routes"
ROUTES_PACKAGE = "bayesian_fields_service.api.routes"

#: What the state must not hand a route: infrastructure, however wrapped (Optional, a union).
INFRASTRUCTURE: tuple[type, ...] = (Store, redis.Redis, Engine, Connection)
#: Modules a route must not import (a module or any of its submodules).
FORBIDDEN_IMPORTS = ("bayesian_fields_service.records", "redis", "sqlalchemy")
#: Attributes through which a route would reach the infrastructure behind a domain.
FORBIDDEN_ATTRIBUTES = frozenset({"database", "redis", "store"})


def _types_in(hint: object) -> list[type]:
    """The classes a field's type names (the members of a union; a generic and its arguments)."""
    origin = typing.get_origin(hint)
    named = [t for arg in typing.get_args(hint) for t in _types_in(arg)]
    if origin in (typing.Union, types.UnionType):
        return named
    if origin is not None:
        return [*_types_in(origin), *named]
    return [hint] if isinstance(hint, type) else []


def infrastructure_fields(cls: type) -> list[str]:
    """`cls`'s dataclass fields whose type is (or may be) a bucket, Redis client or engine."""
    hints = typing.get_type_hints(cls)
    return [
        f"{f.name}: {hints[f.name]}"
        for f in dataclasses.fields(cls)
        if any(issubclass(t, INFRASTRUCTURE) for t in _types_in(hints[f.name]))
    ]


def _imported(node: ast.Import | ast.ImportFrom) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    base = node.module or ""
    if node.level:
        parts = ROUTES_PACKAGE.split(".")
        base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
    return [base, *(f"{base}.{alias.name}" for alias in node.names)]


def infrastructure_uses(source: str, name: str) -> list[str]:
    """Where the route module `name` (its `source`) imports or reaches the infrastructure."""
    found = []
    for node in ast.walk(ast.parse(source, name)):
        where = f"{name}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Import | ast.ImportFrom):
            for module in _imported(node):
                if any(module == bad or module.startswith(bad + ".") for bad in FORBIDDEN_IMPORTS):
                    found.append(f"{where}: imports {module}")
        elif isinstance(node, ast.Attribute) and node.attr in FORBIDDEN_ATTRIBUTES:
            found.append(f"{where}: reaches .{node.attr}")
    return found


def test_app_state_holds_no_infrastructure() -> None:
    names = {f.name for f in dataclasses.fields(AppState)}
    assert {"settings", "jobs", "service", "scenes", "answers", "key_ring"} <= names  # read the real one
    assert infrastructure_fields(AppState) == [], "AppState hands routes infrastructure; give it a domain"


def test_the_field_check_catches_infrastructure() -> None:
    @dataclasses.dataclass
    class Leaky:
        settings: int
        bucket: PrefixedStore  # a subclass of Store
        client: redis.Redis | None
        engine: typing.Optional[Engine]  # noqa: UP045 (the other spelling of a union, on purpose)
        rows: list[Connection]

    found = infrastructure_fields(Leaky)
    assert [f.split(":")[0] for f in found] == ["bucket", "client", "engine", "rows"], found


def test_no_route_imports_or_reaches_the_infrastructure() -> None:
    modules = sorted(ROUTES.glob("*.py"))
    assert {"answers.py", "health.py", "jobs.py", "metrics.py", "usage.py"} <= {p.name for p in modules}
    found = [use for path in modules for use in infrastructure_uses(path.read_text(), path.name)]
    listing = "\n".join(found)
    assert found == [], f"routes call a domain, never the infrastructure (issue 43):\n{listing}"


def test_the_route_scan_catches_each_kind_of_probe() -> None:
    probes = {
        "import redis\n": "imports redis",
        "import redis.exceptions\n": "imports redis.exceptions",
        "from sqlalchemy import Engine\n": "imports sqlalchemy",
        "from bayesian_fields_service.records import answers\n": "imports bayesian_fields_service.records",
        "from bayesian_fields_service import records\n": "imports bayesian_fields_service.records",
        "from bayesian_fields_service.records.ids import BATCH_ID\n": "records.ids",
        "from ...records import answers\n": "imports bayesian_fields_service.records",
        "state.jobs.database\n": "reaches .database",
        "s.redis.ping()\n": "reaches .redis",
        "state.store.list('x/')\n": "reaches .store",
    }
    for source, expected in probes.items():
        found = infrastructure_uses(source, "probe.py")
        assert found and all(expected in f for f in found), (source, found)
    fine = (
        "from bayesian_fields_service.jobs.answers import AnswerFilter\n"
        "from bayesian_fields_service.api.state import State\n"
        "state.answers.fleet('t', 'chair', limit=1)\n"
        "state.jobs.local_file('t', 'jobs/j/result/a.png')\n"
    )
    assert infrastructure_uses(fine, "fine.py") == []
