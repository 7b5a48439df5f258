"""Reading the JSON-lines span files the service's processes write (``BFIELDS_TRACING=file:PATH``,
`observability.span_files`): one trace's spans, its root, and its tree as text."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

Span = dict[str, Any]


def read_spans(path: Path) -> list[Span]:
    """Every span in the file; each line must be one JSON object."""
    return [json.loads(line) for line in path.read_text().splitlines() if line]


def trace_spans(spans: list[Span], trace_id: str) -> list[Span]:
    return [s for s in spans if s["trace_id"] == trace_id]


def roots(spans: list[Span]) -> list[Span]:
    return [s for s in spans if s["parent_id"] is None]


def children(spans: list[Span]) -> dict[str | None, list[Span]]:
    """Parent span id -> its spans, by start time."""
    out: dict[str | None, list[Span]] = defaultdict(list)
    for s in sorted(spans, key=lambda s: s["start_ns"]):
        out[s["parent_id"]].append(s)
    return out


def ancestors(spans: list[Span], span: Span) -> list[str]:
    """Names of the span's ancestors, nearest first."""
    by_id = {s["span_id"]: s for s in spans}
    names = []
    parent = span["parent_id"]
    while parent is not None:
        names.append(by_id[parent]["name"])
        parent = by_id[parent]["parent_id"]
    return names


#: Attributes shown beside a span's name in the tree.
SHOWN = ("bfields.frames", "bfields.frames_computed", "bfields.frames_cached", "bfields.masks_computed",
         "bfields.masks", "bfields.gaussians", "bfields.primitives", "bfields.objects")  # fmt: skip


def call_kind(span: Span) -> str | None:
    """'SQL', 'Redis' or 'S3' for a leaf call to one of them, None for any other span."""
    attributes = span["attributes"]
    if attributes.get("rpc.service") == "S3":
        return "S3"
    system = attributes.get("db.system") or attributes.get("db.system.name")
    if system == "redis":
        return "Redis"
    if system == "postgresql":
        return "SQL"
    return None


def render(spans: list[Span]) -> str:
    """The trace as an indented tree: name, process, milliseconds and the counts; a span's SQL,
    Redis and S3 calls summed up in one line under it (a trace has hundreds)."""
    kids = children(spans)
    lines: list[str] = []

    def label(s: Span) -> str:
        ms = (s["end_ns"] - s["start_ns"]) / 1e6
        counts = " ".join(f"{k.removeprefix('bfields.')}={s['attributes'][k]}" for k in SHOWN
                          if k in s["attributes"])  # fmt: skip
        return f"{s['name']}  [{s['service']}] {ms:.0f} ms" + (f"  {counts}" if counts else "")

    def walk(parent: str | None, depth: int) -> None:
        calls: dict[str, int] = defaultdict(int)
        others = []
        for s in kids.get(parent, []):
            kind = call_kind(s)
            if kind is not None and not kids.get(s["span_id"]):
                calls[kind] += 1
            else:
                others.append(s)
        if calls:
            lines.append("  " * depth + "(" + ", ".join(f"{k} x{n}" for k, n in sorted(calls.items())) + ")")
        for s in others:
            lines.append("  " * depth + label(s))
            walk(s["span_id"], depth + 1)

    walk(None, 0)
    return "\n".join(lines)
