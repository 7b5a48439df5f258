"""Task lists: plain-language tasks such as "get dish soap", read from YAML, JSON or text."""

from __future__ import annotations

import json
import unicodedata
from pathlib import Path

import yaml

from bayesian_fields_core.errors import InputError

MAX_TASKS = 256
MAX_TASK_CHARS = 200

#: Bidirectional controls (embeddings, overrides, isolates, marks): they make a task display
#: differently from what the encoder reads ("Trojan Source"), so tasks carrying them are refused.
BIDI_CONTROLS = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def check_task_text(text: str) -> str | None:
    """Why `text` is not acceptable as a task, or None.

    Refused rather than normalised, so a stored task is always exactly what the client sent (up to
    whitespace): lone UTF-16 surrogates (not encodable as UTF-8), control characters other than
    whitespace (which is collapsed to single spaces), and bidirectional controls."""
    for pos, ch in enumerate(text):
        cat = unicodedata.category(ch)
        if cat == "Cs":
            return f"contains a lone surrogate U+{ord(ch):04X} at position {pos} (not valid UTF-8)"
        if ch in BIDI_CONTROLS:
            return f"contains the bidirectional control U+{ord(ch):04X} at position {pos}"
        if cat == "Cc" and not ch.isspace():
            return f"contains the control character U+{ord(ch):04X} at position {pos}"
    return None


def normalise_tasks(
    raw: object, *, source: str = "tasks", max_tasks: int = MAX_TASKS, max_chars: int = MAX_TASK_CHARS
) -> list[str]:
    """Validate a task list: strings, non-empty, unique, bounded in count and length (the service
    passes its configured limits), free of control characters (see `check_task_text`).

    Accepts a list of strings, a list of {"task": ...} / {"name": ...} entries (the form the
    synthetic scenes' tasks.yaml uses, which carries extra fields) or {"tasks": [...]}.
    """
    if isinstance(raw, dict) and "tasks" in raw:
        raw = raw["tasks"]
    if not isinstance(raw, list):
        raise InputError("expected a list of tasks (or a mapping with a 'tasks' list)", source=source)
    tasks: list[str] = []
    for i, item in enumerate(raw):
        if isinstance(item, dict):
            item = item.get("task", item.get("name", item.get("text")))
        if not isinstance(item, str) or not item.strip():
            raise InputError(f"task #{i + 1} is not a non-empty string", source=source)
        if (why := check_task_text(item)) is not None:
            raise InputError(f"task #{i + 1} {why}", source=source)
        text = " ".join(item.split())
        if len(text) > max_chars:
            raise InputError(f"task #{i + 1} is longer than {max_chars} characters", source=source)
        tasks.append(text)
    if not tasks:
        raise InputError("the task list is empty", source=source)
    if len(tasks) > max_tasks:
        raise InputError(f"{len(tasks)} tasks; at most {max_tasks} are allowed", source=source)
    duplicates = sorted({t for t in tasks if tasks.count(t) > 1})
    if duplicates:
        raise InputError(f"duplicate tasks: {duplicates}", source=source)
    return tasks


def load_tasks(path: str | Path) -> list[str]:
    """Read tasks from .yaml/.yml, .json, or a text file with one task per line."""
    path = Path(path)
    if path.is_dir():
        raise InputError(
            "is a folder; expected a tasks file (.yaml list, .json or one task per line)", source=str(path)
        )
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except UnicodeDecodeError:
        raise InputError("not UTF-8 text", source=str(path)) from None
    try:
        if path.suffix in (".yaml", ".yml"):
            raw = yaml.safe_load(text)
        elif path.suffix == ".json":
            raw = json.loads(text)
        else:
            raw = [line.strip() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    except (yaml.YAMLError, ValueError) as exc:  # ValueError: JSON errors, int-digit limit
        raise InputError(f"cannot parse: {exc}", source=str(path)) from None
    except RecursionError:
        raise InputError("cannot parse: nested too deeply", source=str(path)) from None
    return normalise_tasks(raw, source=str(path))
