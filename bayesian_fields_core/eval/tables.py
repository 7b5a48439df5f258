"""Plain-text and markdown tables for the evaluation reports (the paper's tables' layout)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence


def render_table(header: Sequence[str], rows: Sequence[Sequence[str]], *, markdown: bool = False) -> str:
    """A table with the first column left-aligned and the others right-aligned: aligned plain text
    (two spaces between columns, a rule under the header) or a GitHub markdown table."""
    if markdown:
        lines = [
            "| " + " | ".join(header) + " |",
            "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|",
        ]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def fmt(cells: Sequence[str]) -> str:
        rest = [c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True)]
        return "  ".join([cells[0].ljust(widths[0]), *rest])

    return "\n".join([fmt(header), "-" * len(fmt(header)), *(fmt(r) for r in rows)])


def format_interval_table(
    rows: Mapping[str, Mapping[str, object]], *, level: float = 0.95, markdown: bool = False
) -> str:
    """Table 1's scores with their intervals: one row per method, one "value [low, high]" cell
    per metric (strict_osr, relaxed_osr, iou), as `bootstrap.score_intervals` gives them."""
    header = ["Method", f"Strict-osR ({level:.0%} CI)", "Relaxed-osR", "IoU"]
    body = [[name, str(m["strict_osr"]), str(m["relaxed_osr"]), str(m["iou"])] for name, m in rows.items()]
    return render_table(header, body, markdown=markdown)
