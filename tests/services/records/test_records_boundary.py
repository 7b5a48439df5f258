"""Only `records/` issues SQL (issue 43 item 1): no module of the service outside it (its
migrations are inside) builds or runs a statement or opens a transaction by itself. The domains
open the unit of work through `records.begin` / `records.connect` and call the repositories.

What counts, read from each module's syntax tree:
- importing anything from SQLAlchemy but the names a caller needs to hold an engine or a
  connection, make one, or catch its errors (`ALLOWED`; all of `sqlalchemy.exc`), or importing
  the package itself (``import sqlalchemy as sa`` reaches ``sa.text``);
- calling ``.execute(...)`` with an argument (a statement; a Redis pipeline's ``execute()``
  takes none);
- calling ``.begin()`` or ``.connect()`` with no argument (an engine's transaction or
  connection; `records.begin(engine)` takes one).
"""

from __future__ import annotations

import ast
from pathlib import Path

SERVICES = Path(__file__).resolve().parents[3] / "services"
RECORDS = SERVICES / "records"

#: SQLAlchemy names a module outside records/ may import, by the module they come from.
ALLOWED: dict[str, set[str]] = {
    "sqlalchemy": {"Engine", "Connection", "create_engine"},
    "sqlalchemy.engine": {"Engine", "Connection", "make_url"},
    "sqlalchemy.pool": {"QueuePool"},
}


def sql_uses(source: str, name: str) -> list[str]:
    """Where `source` (the module `name`) issues SQL by itself, one line each."""
    found = []
    for node in ast.walk(ast.parse(source, name)):
        where = f"{name}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "sqlalchemy":
            module = node.module or ""
            if module == "sqlalchemy.exc":
                continue
            for alias in node.names:
                if alias.name not in ALLOWED.get(module, set()):
                    found.append(f"{where}: imports {alias.name} from {module}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "sqlalchemy" and alias.name != "sqlalchemy.exc":
                    found.append(f"{where}: imports {alias.name}")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            attr, args = node.func.attr, node.args or node.keywords
            if attr == "execute" and args:
                found.append(f"{where}: calls .execute(...) with a statement")
            elif attr in ("begin", "connect") and not args:
                found.append(f"{where}: calls .{attr}() (open the unit of work with records.{attr}(engine))")
    return found


def _modules() -> list[Path]:
    return [p for p in sorted(SERVICES.rglob("*.py")) if RECORDS not in p.parents]


def test_no_module_outside_records_issues_sql() -> None:
    assert len(_modules()) > 50  # the walk found the service
    found = [
        use for path in _modules() for use in sql_uses(path.read_text(), str(path.relative_to(SERVICES)))
    ]
    listing = "\n".join(found)
    assert found == [], f"SQL outside services/records/ (move it into a repository there):\n{listing}"


def test_the_check_catches_each_kind_of_probe() -> None:
    probes = {
        "from sqlalchemy import select\n": "imports select",
        "from sqlalchemy import Engine, text\n": "imports text",
        "from sqlalchemy.dialects.postgresql import insert\n": "imports insert",
        "import sqlalchemy as sa\n": "imports sqlalchemy",
        "conn.execute(statement)\n": ".execute(...)",
        "conn.execute(statement=q)\n": ".execute(...)",
        "with engine.begin() as conn:\n    pass\n": ".begin()",
        "with self.database.connect() as conn:\n    pass\n": ".connect()",
    }
    for source, expected in probes.items():
        found = sql_uses(source, "probe.py")
        assert len(found) == 1 and expected in found[0], (source, found)


def test_what_holds_an_engine_or_talks_to_redis_passes() -> None:
    fine = (
        "from sqlalchemy import Connection, Engine\n"
        "from sqlalchemy.exc import DBAPIError, OperationalError\n"
        "import sqlalchemy.exc\n"
        "from bayesian_fields_service import records\n"
        "pipe.execute()\n"
        "with records.begin(engine) as conn:\n    pass\n"
    )
    assert sql_uses(fine, "fine.py") == []
