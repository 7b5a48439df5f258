"""`bfields cache ls | prune`: see and bound the local cache folder, all of it.

The cache lives in ``--cache-dir`` (default ``$XDG_CACHE_HOME/bfields``, else ``~/.cache/bfields``):
``perception/<models>/<image digest>.npz``, ``visibility/<models>/<digest>.npz`` and ``index/``, one
JSON per scene + profile (see `cache_index`), and ``view/<job id>/``, the results `bfields view
--job` downloaded (see `cache_folder`). `ls` reports the folder's whole size on disk; `prune`
applies its limits to both kinds: `--older-than` to each entry and download alike, `--max-size`
to their sum, removing downloads (least recently viewed first; a view downloads them again) before
frames (which cost perception to compute again).
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
    cache = sub.add_parser(
        "cache", help="list or prune the local cache (perception/visibility frames, view downloads)"
    )
    cache_sub = cache.add_subparsers(dest="cache_command", required=True)
    ls = cache_sub.add_parser(
        "ls", help="entries (scene + profile) and `view --job` downloads, with size and last use"
    )
    ls.add_argument("--json", action="store_true", help="print the listing as JSON")
    prune_parser = cache_sub.add_parser("prune", help="drop entries and downloads least recently used first")
    prune_parser.add_argument(
        "--older-than",
        type=parse_duration,
        metavar="DUR",
        help="drop entries and view downloads unused for DUR (30m, 12h, 7d)",
    )
    prune_parser.add_argument(
        "--max-size",
        type=parse_size,
        metavar="SIZE",
        help="then keep at most SIZE (500M, 2G): view downloads go first, then entries, LRU first",
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
    """The listing `bfields cache ls` prints: the folder's size on disk (every file in it), one
    line per scene + profile and one per `view --job` download, most recent first."""
    import json

    from bayesian_fields_core.cli.cache_folder import disk_usage, view_downloads
    from bayesian_fields_core.job.cache_index import list_entries

    store = _store(cache_dir)
    entries = list_entries(store)
    downloads = view_downloads(cache_dir)
    total = disk_usage(cache_dir)
    now = time.time()
    if json_output:
        return json.dumps(
            {
                "cache_dir": str(store.root),
                "bytes_on_disk": total,
                "entries": [
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
                "view_downloads": [
                    {
                        "job": d.job,
                        "path": str(d.path),
                        "files": d.files,
                        "bytes": d.size,
                        "last_used_s_ago": round(now - d.last_used, 1),
                    }
                    for d in downloads
                ],
            },
            indent=2,
        )
    lines = [
        f"cache {store.root}: {len(entries)} entries, {len(downloads)} view downloads, "
        f"{human_size(total)} on disk"
    ]
    if entries:
        lines.append(
            f"{'last used':>10}  {'size':>10}  {'files':>5}  {'scene id':<16}  profile (models)  scene"
        )
    for e in entries:
        lines.append(
            f"{human_age(now - e.last_used) + ' ago':>10}  {human_size(e.size):>10}  {len(e.keys):>5}  "
            f"{e.scene_id:<16}  {e.profile} ({e.fingerprint})  {e.scene}"
        )
    if downloads:
        lines.append(f"view downloads (bfields view --job), {human_size(sum(d.size for d in downloads))}:")
        lines.append(f"{'last used':>10}  {'size':>10}  {'files':>5}  job")
    for d in downloads:
        lines.append(
            f"{human_age(now - d.last_used) + ' ago':>10}  {human_size(d.size):>10}  {d.files:>5}  {d.job}"
        )
    return "\n".join(lines)


def cache_prune(cache_dir: Path, *, older_than_s: float | None, max_size: int | None) -> str:
    """Prune entries and view downloads (the rule is the module's) and describe what was removed."""
    from bayesian_fields_core.cli.cache_folder import disk_usage, remove_download, view_downloads
    from bayesian_fields_core.job.cache_index import prune

    store = _store(cache_dir)
    now = time.time()
    kept = view_downloads(cache_dir)  # most recently viewed first
    dropped = [d for d in kept if older_than_s is not None and now - d.last_used > older_than_s]
    kept = [d for d in kept if d not in dropped]
    report = prune(store, older_than_s=older_than_s, now=now)
    entries, files, freed = report.entries_removed, report.files_removed, report.bytes_freed
    if max_size is not None:
        while kept and report.bytes_left + sum(d.size for d in kept) > max_size:
            dropped.append(kept.pop())  # the least recently viewed
        report = prune(store, max_size=max(max_size - sum(d.size for d in kept), 0), now=now)
        entries, files, freed = (
            entries + report.entries_removed,
            files + report.files_removed,
            freed + report.bytes_freed,
        )
    for d in dropped:
        remove_download(d)
    return (
        f"removed {entries} entries and {files} files ({human_size(freed)}), "
        f"{len(dropped)} view downloads ({human_size(sum(d.size for d in dropped))}); "
        f"{human_size(disk_usage(cache_dir))} left in {store.root}"
    )
