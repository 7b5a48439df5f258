"""`bfields cache ls | prune`: see and bound the local perception/visibility cache.

The cache lives in ``--cache-dir`` (default ``$XDG_CACHE_HOME/bfields``, else ``~/.cache/bfields``):
``perception/<models>/<image digest>.npz``, ``visibility/<models>/<digest>.npz`` and ``index/``, one
JSON per scene + profile (see `cache_index`).
"""

from __future__ import annotations

import argparse
import os
import re
import time
from pathlib import Path
from typing import TYPE_CHECKING

from bayesian_fields_core.errors import InputError

if TYPE_CHECKING:
    from bayesian_fields_core.job.store import LocalStore

DEFAULT_CACHE_DIR = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "bfields"
"""Where `bfields run`, `bfields cache` and `bfields view --job` keep what they cache."""

_DURATION_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}
_SIZE_UNITS = {"": 1, "b": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def parse_duration(text: str) -> float:
    """'90s', '30m', '12h', '7d', '2w' (a bare number is seconds) -> seconds."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smhdw]?)\s*", text.lower())
    if m is None:
        raise argparse.ArgumentTypeError(f"expected a duration such as 30m, 12h or 7d, got {text!r}")
    return float(m.group(1)) * _DURATION_UNITS[m.group(2) or "s"]


def parse_size(text: str) -> int:
    """'500M', '2G', '1.5GB', '100k', '4096' (binary units) -> bytes."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kmgt]?)(?:i?b)?\s*", text.lower())
    if m is None:
        raise argparse.ArgumentTypeError(f"expected a size such as 500M or 2G, got {text!r}")
    return int(float(m.group(1)) * _SIZE_UNITS[m.group(2)])


def register(sub: argparse._SubParsersAction) -> None:
    """Add `cache ls | prune` to the `bfields` parser."""
    cache = sub.add_parser("cache", help="list or prune the local perception/visibility cache")
    cache_sub = cache.add_subparsers(dest="cache_command", required=True)
    ls = cache_sub.add_parser("ls", help="entries (scene + profile) with size and last use")
    ls.add_argument("--json", action="store_true", help="print the entries as JSON")
    prune_parser = cache_sub.add_parser("prune", help="drop entries least recently used first")
    prune_parser.add_argument(
        "--older-than", type=parse_duration, metavar="DUR", help="drop entries unused for DUR (30m, 12h, 7d)"
    )
    prune_parser.add_argument(
        "--max-size", type=parse_size, metavar="SIZE", help="then keep at most SIZE (500M, 2G), LRU first"
    )
    for p in (ls, prune_parser):
        p.add_argument("--cache-dir", help=f"the cache folder (default {DEFAULT_CACHE_DIR})")
    cache.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """List or prune the cache in --cache-dir (default `DEFAULT_CACHE_DIR`)."""
    cache_dir = Path(args.cache_dir) if args.cache_dir else DEFAULT_CACHE_DIR
    if args.cache_command == "ls":
        print(cache_ls(cache_dir, json_output=args.json))
    else:
        if args.older_than is None and args.max_size is None:
            raise InputError("give --older-than DUR and/or --max-size SIZE", source="cache prune")
        print(cache_prune(cache_dir, older_than_s=args.older_than, max_size=args.max_size))
    return 0


def human_size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024  # type: ignore[assignment]
    return f"{n} B"


def human_age(seconds: float) -> str:
    for unit, span in (("d", 86400), ("h", 3600), ("m", 60)):
        if seconds >= span:
            return f"{seconds / span:.1f}{unit}"
    return f"{seconds:.0f}s"


def _store(cache_dir: Path) -> LocalStore:
    from bayesian_fields_core.job.store import LocalStore

    if cache_dir.exists() and not cache_dir.is_dir():
        raise InputError("not a folder", source=str(cache_dir))
    return LocalStore(cache_dir)


def cache_ls(cache_dir: Path, *, json_output: bool = False) -> str:
    """The listing `bfields cache ls` prints: one line per scene + profile, most recent first."""
    import json

    from bayesian_fields_core.job.cache_index import data_keys, list_entries

    store = _store(cache_dir)
    entries = list_entries(store)
    now = time.time()
    if json_output:
        return json.dumps(
            [
                {
                    "scene": e.scene,
                    "scene_id": e.scene_id,
                    "profile": e.profile,
                    "fingerprint": e.fingerprint,
                    "frames": e.frames,
                    "files": len(e.keys),
                    "bytes": e.size,
                    "last_used_s_ago": round(now - e.last_used, 1),
                }
                for e in entries
            ],
            indent=2,
        )
    total = sum(store.size(k) for k in data_keys(store))
    lines = [f"cache {store.root}: {len(entries)} entries, {human_size(total)} on disk"]
    if entries:
        lines.append(
            f"{'last used':>10}  {'size':>10}  {'files':>5}  {'scene id':<16}  profile (models)  scene"
        )
    for e in entries:
        lines.append(
            f"{human_age(now - e.last_used) + ' ago':>10}  {human_size(e.size):>10}  {len(e.keys):>5}  "
            f"{e.scene_id:<16}  {e.profile} ({e.fingerprint})  {e.scene}"
        )
    return "\n".join(lines)


def cache_prune(cache_dir: Path, *, older_than_s: float | None, max_size: int | None) -> str:
    """Prune and describe what was removed."""
    from bayesian_fields_core.job.cache_index import prune

    store = _store(cache_dir)
    report = prune(store, older_than_s=older_than_s, max_size=max_size)
    return (
        f"removed {report.entries_removed} entries and {report.files_removed} files "
        f"({human_size(report.bytes_freed)}); {human_size(report.bytes_left)} left in {store.root}"
    )
