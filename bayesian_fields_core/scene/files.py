"""Small file helpers shared by the camera readers and the scene loader."""

from __future__ import annotations

import json
import posixpath
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError, describe_failure


def load_json(path: Path) -> Any:
    """Parse a JSON file, turning every failure into an InputError naming the file."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError as exc:
        raise InputError("file not found", source=str(path)) from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc})", source=str(path)) from exc
    except (OSError, UnicodeError, ValueError, RecursionError, MemoryError) as exc:
        # ValueError: an integer longer than Python's int-digits limit; RecursionError: nesting.
        raise InputError(f"not valid JSON ({describe_failure(exc)})", source=str(path)) from exc


def require_files(
    paths: Iterable[Path | None], *, what: str, source: str, fix: str = "", shown: int = 5
) -> None:
    """InputError listing (the first few of) the paths that are not existing files, then `fix`
    (what the user can do about it), when given."""
    missing = [str(p) for p in paths if p is None or not Path(p).is_file()]
    if missing:
        more = f" and {len(missing) - shown} more" if len(missing) > shown else ""
        raise InputError(
            f"{len(missing)} {what} referenced by the cameras do not exist: {', '.join(missing[:shown])}{more}"
            + (f"; {fix}" if fix else ""),
            source=source,
        )


def resolve_inside(root: str | Path, name: str, *, what: str, source: str) -> Path:
    """`root / name` with symlinks resolved, refused unless it stays inside `root`.

    Why: camera files name image and depth paths, and an upload's camera file must never make the
    API or a worker open a host file. The name is first checked lexically (absolute, NUL, a `..`
    that climbs out), which touches no file; only a name that stays inside is then resolved,
    following symlinks, and re-checked. All of this runs before any existence test and the
    message never depends on what exists outside, so there is no file-existence oracle.
    """
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{what} path must be a non-empty string, got {name!r}", source=source)
    if "\x00" in name:
        raise InputError(f"{what} path contains a NUL byte", source=source)
    if Path(name).is_absolute():
        raise InputError(
            f"{what} path {name!r} is absolute; paths must be relative to the scene folder", source=source
        )
    lexical = posixpath.normpath(name)
    if lexical == ".." or lexical.startswith("../"):
        raise InputError(f"{what} path {name!r} leaves the scene folder", source=source)
    try:
        base = Path(root).resolve()
        resolved = (base / lexical).resolve()
    except (OSError, RuntimeError, ValueError) as exc:  # symlink loop, name too long
        raise InputError(
            f"{what} path {name!r} cannot be resolved ({describe_failure(exc)})", source=source
        ) from None
    if not resolved.is_relative_to(base):
        raise InputError(f"{what} path {name!r} leaves the scene folder", source=source)
    return resolved
