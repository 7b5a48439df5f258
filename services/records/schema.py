"""The current schema as one readable file, `schema.sql` beside the migrations, and how it is made.

Why generated and checked rather than written by hand: the tables and indexes are declared once,
in `tables.metadata` (a test, `test_migrations`, proves the migrations create exactly that), and
the batch counters exist as trigger SQL that only a migration (0003) can hold, because a migration
must stay what it was when it ran. So `schema.sql` is the metadata's DDL compiled for PostgreSQL
(no server needed) followed by the trigger SQL read from the migration that defines it
(`TRIGGER_SOURCES`); `tests/services/records/test_schema_file.py` fails when the file differs and
names the command that rewrites it:

    PYTHONPATH=$PWD python -m bayesian_fields_service.records.schema --write

A migration that replaces the triggers is added to `TRIGGER_SOURCES` (the newest wins per name).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from sqlalchemy.dialects import postgresql
from sqlalchemy.schema import CreateIndex, CreateTable

from bayesian_fields_service.records.database import MIGRATIONS
from bayesian_fields_service.records.tables import metadata

SCHEMA_FILE = Path(__file__).resolve().parent / "schema.sql"

#: (migration file, names of its module-level SQL strings) holding the current functions and triggers.
TRIGGER_SOURCES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("0003_batch_statements.py", ("_APPLY", "_JOBS_TRIGGER", "_LINK_TRIGGERS")),
)

FIX_COMMAND = "PYTHONPATH=$PWD python -m bayesian_fields_service.records.schema --write"

_HEADER = f"""\
-- The records' current schema (PostgreSQL), generated: do not edit by hand.
-- Tables and indexes: `tables.metadata`; functions and triggers: the migrations named below.
-- Rewrite with: {FIX_COMMAND}
"""


def _migration(file_name: str) -> ModuleType:
    """A migration script loaded by path (the versions folder is not an importable package name)."""
    path = MIGRATIONS / "versions" / file_name
    spec = importlib.util.spec_from_file_location(f"_bfields_migration_{path.stem}", path)
    assert spec is not None and spec.loader is not None, path
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def render() -> str:
    """The text `schema.sql` must hold."""
    dialect = postgresql.dialect()
    parts = [_HEADER]
    for table in metadata.sorted_tables:
        parts.append(f"{str(CreateTable(table).compile(dialect=dialect)).strip()};\n")
        for index in sorted(table.indexes, key=lambda i: str(i.name)):
            parts.append(f"{str(CreateIndex(index).compile(dialect=dialect)).strip()};\n")
    for file_name, names in TRIGGER_SOURCES:
        module = _migration(file_name)
        parts.append(f"-- functions and triggers of migration {file_name}")
        parts.extend(str(getattr(module, name)).strip() + "\n" for name in names)
    text = "\n".join(parts)  # SQLAlchemy indents with tabs and ends lines with ", ": tidied
    return "\n".join(line.rstrip().replace("\t", "    ") for line in text.splitlines()) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Print the schema, or with ``--write`` rewrite `schema.sql`."""
    args = sys.argv[1:] if argv is None else argv
    text = render()
    if args == ["--write"]:
        SCHEMA_FILE.write_text(text)
        print(f"wrote {SCHEMA_FILE}")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
