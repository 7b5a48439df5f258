"""The pipeline parameters as rows of a table: name, type, default, who reads it, description.

Generated from `PipelineParams` alone (the "read by" column from each field's `ReadBy` marker,
the same one the cache keys derive from), so the docs' parameter table, `bfields params` and
`bfields run --help` can never disagree with the model (a test compares the docs' page with
`markdown_table()`).
"""

from __future__ import annotations

import json
import types
import typing
from dataclasses import dataclass
from typing import Any, Literal

from bayesian_fields_core.params import PipelineParams, ReadBy, read_by


@dataclass(frozen=True)
class ParamRow:
    """One field of `PipelineParams`, rendered for people."""

    name: str
    type: str
    default: str
    read_by: str
    description: str


def type_name(annotation: Any) -> str:
    """`int`, `float | None`, `bayes|average` (a Literal lists its choices), `float | calibrated |
    None` (an Annotated member shows its base type)."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:  # a constrained type (bounds live in the Field): its base type
        return type_name(typing.get_args(annotation)[0])
    if origin is Literal:
        return "|".join(str(v) for v in typing.get_args(annotation))
    if origin in (typing.Union, types.UnionType):
        return " | ".join(type_name(a) for a in typing.get_args(annotation))
    if annotation is type(None):
        return "None"
    return getattr(annotation, "__name__", str(annotation))


def default_text(value: Any) -> str:
    """A default as a user writes it in `--param` or a JSON `parameters` object."""
    if isinstance(value, str):
        return value
    return json.dumps(value)


def reader_text(reader: ReadBy) -> str:
    """`fuse: visibility; keys the visibility cache`: the stages, what for, and the caches it keys
    (`fuse, cluster: fusion update` for a field more than one stage reads)."""
    keys = f"; keys the {' and '.join(reader.keys)} cache" if reader.keys else ""
    return f"{', '.join(reader.stages)}: {reader.why}{keys}"


def rows() -> list[ParamRow]:
    """Every field of `PipelineParams`, in declaration order."""
    return [
        ParamRow(
            name,
            type_name(f.annotation),
            default_text(f.default),
            reader_text(read_by(name)),
            f.description or "",
        )
        for name, f in PipelineParams.model_fields.items()
    ]


def markdown_table() -> str:
    """The docs' parameter table (docs/guide/parameters.md, `bfields params --markdown`)."""
    lines = ["| parameter | type | default | read by | meaning |", "|---|---|---|---|---|"]
    for r in rows():
        cells = (f"`{r.name}`", f"`{r.type}`", f"`{r.default}`", r.read_by, r.description)
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


def text_table(width: int = 100) -> str:
    """The same rows for a terminal (`bfields params`): name, type, default, reader, then the
    wrapped description indented under them."""
    import textwrap

    out = []
    for r in rows():
        out.append(f"{r.name}  ({r.type}, default {r.default}; read by {r.read_by})")
        out.extend(textwrap.wrap(r.description, width=width, initial_indent="    ", subsequent_indent="    "))
    return "\n".join(out) + "\n"
