"""`bfields compare RESULT_A RESULT_B [--all] [--json]`: which objects of run B are the same,
changed, split, merged or new against run A (and which of A are gone), matched by their Gaussians
(`results.compare` states the rule). The table lists the objects that answer a task in either run
(`--all`: every object); `--json` prints every row."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bayesian_fields_core.results.compare import ObjectMatch
    from bayesian_fields_core.results.format import Result


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `compare` verb."""
    compare = subparsers.add_parser(
        "compare",
        help="match the objects of two runs of one scene: same / changed / split / merged / new / gone",
        description="Object ids are per run; this matches two runs' objects by their Gaussians. "
        "Rules: docs, 'Result format', object ids and keys.",
    )
    compare.add_argument("result_a", metavar="RESULT_A", help="the earlier run folder (or its result/)")
    compare.add_argument("result_b", metavar="RESULT_B", help="the later run folder (or its result/)")
    compare.add_argument("--all", action="store_true", help="list every object, not only the tasks' answers")
    compare.add_argument("--json", action="store_true", help="every row and the counts as JSON")
    compare.set_defaults(func=run)


def _answers(result: Result) -> dict[int, list[str]]:
    """{object id: the tasks it answers} of one run."""
    tasks: dict[int, list[str]] = {}
    for task, objects in result.selections.items():
        for obj in objects:
            tasks.setdefault(obj.object_id, []).append(task)
    return tasks


def _tasks_of(
    row: ObjectMatch, answers_a: dict[int, list[str]], answers_b: dict[int, list[str]]
) -> list[str]:
    found = list(answers_b.get(row.object_b, [])) if row.object_b is not None else []
    for obj in row.objects_a:
        found += [t for t in answers_a.get(obj, []) if t not in found]
    return found


def run(args: argparse.Namespace) -> int:
    from bayesian_fields_core.results.compare import compare_results, status_counts
    from bayesian_fields_core.results.reader import read_result

    a, b = read_result(args.result_a), read_result(args.result_b)
    rows = compare_results(a, b)
    answers_a, answers_b = _answers(a), _answers(b)
    if args.json:
        doc: dict[str, Any] = {
            "a": str(args.result_a),
            "b": str(args.result_b),
            "counts": status_counts(rows),
            "objects": [{**r.to_dict(), "tasks": _tasks_of(r, answers_a, answers_b)} for r in rows],
        }
        print(json.dumps(doc, indent=2))
        return 0
    shown = [r for r in rows if args.all or _tasks_of(r, answers_a, answers_b)]
    _print_table(shown, answers_a, answers_b)
    counts = ", ".join(f"{n} {status}" for status, n in status_counts(rows).items())
    print(f"all {len(rows)} objects: {counts}" + ("" if args.all else "  (--all lists them)"))
    return 0


def _print_table(
    rows: list[ObjectMatch], answers_a: dict[int, list[str]], answers_b: dict[int, list[str]]
) -> None:
    """A plain, tab-free table at its natural width (it pipes without wrapping)."""
    header = ["status", "object B", "key B", "Gaussians", "objects A", "shared", "answers to (either run)"]
    body = [
        [
            r.status,
            "-" if r.object_b is None else str(r.object_b),
            r.key_b or "-",
            str(r.gaussians_b) if r.object_b is not None else "-",
            ",".join(map(str, r.objects_a)) or "-",
            str(r.shared) if r.object_b is not None and r.objects_a else "-",
            "; ".join(_tasks_of(r, answers_a, answers_b)) or "-",
        ]
        for r in rows
    ]
    widths = [max(len(line[i]) for line in [header, *body]) for i in range(len(header))]
    for line in [header, *body]:
        print("  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True)).rstrip())
