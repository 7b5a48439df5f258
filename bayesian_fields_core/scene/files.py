"""Small file helpers shared by the camera readers and the scene loader."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError


def load_json(path: Path) -> Any:
    """Parse a JSON file, turning every failure into an InputError naming the file."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError as exc:
        raise InputError("file not found", source=str(path)) from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", source=str(path)) from exc


def require_files(paths: Iterable[Path | None], *, what: str, source: str, shown: int = 5) -> None:
    """InputError listing (the first few of) the paths that are not existing files."""
    missing = [str(p) for p in paths if p is None or not Path(p).is_file()]
    if missing:
        more = f" and {len(missing) - shown} more" if len(missing) > shown else ""
        raise InputError(
            f"{len(missing)} {what} referenced by the cameras do not exist: {', '.join(missing[:shown])}{more}",
            source=source,
        )
