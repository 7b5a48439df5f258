"""`bfields answers (BATCH_ID | --all) --task T`: a batch's or the whole fleet's answers as one
table (issue 42), printed as a table (readable piped: never wrapped or cut), TSV, CSV or JSON.

Why the table shows few columns and the other formats all of them: a person reads task, scene,
rank, probability and where; a script wants every column (the box, its rotation, the keys).
"""

from __future__ import annotations

import csv
import io
import json
import sys
from pathlib import Path
from typing import Any

from rich.table import Table

from bayesian_fields_core.cli.report import stdout_console
from bayesian_fields_core.errors import InputError
from bayesian_fields_service.client.api import BFieldsClient

FORMATS = ("table", "tsv", "csv", "json")
#: The table's columns: (header, row key).
TABLE_COLUMNS = (("task", "task"), ("scene", "scene_name"), ("rank", "rank"), ("object", "object_id"),
                 ("p", "probability"), ("best view", "best_view_score"), ("Gaussians", "num_gaussians"),
                 ("centre", "centre"), ("frame", "frame"), ("job", "job_id"))  # fmt: skip
#: TSV/CSV columns: every column the API lists (`records.answers.COLUMNS`), without its link.
SKIP = ("preview_url",)


def _cell(row: dict[str, Any], key: str) -> str:
    if key == "centre":
        if row.get("centre_x") is None:
            return "-"
        return "(" + ", ".join(f"{row[f'centre_{a}']:+.2f}" for a in "xyz") + ")"
    if key == "scene_name":
        return str(row.get("scene_name") or row["scene_id"])
    value = row.get(key)
    if key == "object_id" and not row.get("found"):
        return f"not found: {row.get('not_found_reason') or ''}".strip()
    if value is None:
        return "-"
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def _flat(value: Any) -> str:
    if value is None:
        return ""
    text = json.dumps(value, separators=(",", ":")) if isinstance(value, list) else str(value)
    return " ".join(text.split())


def render(rows: list[dict[str, Any]], fmt: str) -> str | Table:
    if fmt == "json":
        return json.dumps(rows, indent=2) + "\n"
    if fmt in ("tsv", "csv"):
        columns = [k for k in (rows[0] if rows else {}) if k not in SKIP]
        buffer = io.StringIO()
        if fmt == "csv":
            writer = csv.writer(buffer, lineterminator="\n")
            writer.writerow(columns)
            writer.writerows([[_flat(r.get(c)) for c in columns] for r in rows])
        else:
            buffer.write("\t".join(columns) + "\n")
            buffer.writelines("\t".join(_flat(r.get(c)) for c in columns) + "\n" for r in rows)
        return buffer.getvalue()
    table = Table(title="Answers", show_lines=False)
    for header, _ in TABLE_COLUMNS:
        table.add_column(
            header, justify="right" if header in ("rank", "p", "best view", "Gaussians") else "left"
        )
    for row in rows:
        table.add_row(*(_cell(row, key) for _, key in TABLE_COLUMNS))
    return table


def check(batch_id: str | None, *, everything: bool, task: str | None, fmt: str) -> None:
    """Refuse an impossible request before any connection (one line naming the fix)."""
    if (batch_id is None) == (not everything):
        raise InputError(
            "give either a batch id or --all (every scene of yours), one of the two", source="bfields answers"
        )
    if everything and not task:
        raise InputError("--all needs --task T: the question to ask every scene", source="bfields answers")
    if fmt not in FORMATS:
        raise InputError(f"--format must be one of {', '.join(FORMATS)}", source="bfields answers")


def answers(
    client: BFieldsClient,
    batch_id: str | None,
    *,
    everything: bool,
    task: str | None,
    min_probability: float | None,
    fmt: str,
    out: str | None,
) -> int:
    """Fetch the rows and print or write them; exit 0 (also for no rows)."""
    check(batch_id, everything=everything, task=task, fmt=fmt)
    rows = list(client.answers(batch_id, task=task, min_probability=min_probability))
    shown = render(rows, fmt)
    if out is not None:
        if isinstance(shown, Table):
            console = stdout_console(shown)
            with console.capture() as captured:
                console.print(shown)
            shown = captured.get()
        Path(out).write_text(shown, encoding="utf-8")
        print(f"{len(rows)} answers -> {out}", file=sys.stderr)
        return 0
    if isinstance(shown, Table):
        stdout_console(shown).print(shown)
    else:
        sys.stdout.write(shown)
    return 0
