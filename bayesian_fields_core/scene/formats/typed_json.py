"""JSON a splat format carries (glTF, SOG meta.json), parsed into typed, bounded models.

Why: a reader that indexes a parsed JSON tree directly fails on whatever a hostile file puts
where a number should be (a string count, an object codebook, a list of primitives that are
integers) with a TypeError or an IndexError far from the field. Validating the whole document
against a pydantic model first turns every such field into one message naming the file, the
field's path and what was expected, before any value is used.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from bayesian_fields_core.errors import InputError

Model = TypeVar("Model", bound=BaseModel)
MAX_JSON_BYTES = 32 << 20
"""Largest JSON document a splat format may carry (glTF JSON with embedded buffers, meta.json);
larger ones are refused before they are parsed (a .glb holds its buffers outside the JSON)."""
STRICT = ConfigDict(strict=True, extra="ignore", frozen=True)
"""The models' configuration: no coercion (the string "0" is not an index), unknown keys kept
out of the way (formats carry extensions and generator notes we do not read)."""


def _field_path(loc: tuple[int | str, ...]) -> str:
    return (
        "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in loc).lstrip(".") or "(root)"
    )


def parse_json(raw: bytes, *, source: Path, what: str) -> Any:
    """The JSON value of `raw` (bounded by `MAX_JSON_BYTES`), InputError naming `what` otherwise."""
    if len(raw) > MAX_JSON_BYTES:
        raise InputError(f"{what} is larger than {MAX_JSON_BYTES >> 20} MiB", source=str(source))
    try:
        return json.loads(raw)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(f"{what} is not valid JSON ({str(exc)[:200]})", source=str(source)) from None


def typed(model: type[Model], value: Any, *, source: Path, what: str) -> Model:
    """`value` validated as `model`; InputError naming the first bad fields and what they need."""
    try:
        return model.model_validate(value)
    except ValidationError as exc:
        problems = [f"{_field_path(e['loc'])}: {e['msg']}" for e in exc.errors()[:3]]
        more = f" (and {exc.error_count() - 3} more)" if exc.error_count() > 3 else ""
        raise InputError(f"{what} field {'; '.join(problems)}{more}", source=str(source)) from None
