"""What the cache folder holds besides the frame cache: `bfields view --job` downloads, and the
folder's size as a disk sees it.

`view/<job id>/` is where `bfields view --job` downloads a job's result (each view downloads it
again, so the newest file's modification time is when it was last viewed). `bfields cache ls`
lists these downloads as their own category and `bfields cache prune` removes them by the same
limits as the frame cache's entries; `disk_usage` is the total `ls` reports, so it equals what
`du --apparent-size` says of the folder.
"""

from __future__ import annotations

import os
import shutil
import stat
from dataclasses import dataclass
from pathlib import Path

VIEW_DIR = "view"
"""Folder (inside the cache folder) of `bfields view --job` downloads, one sub-folder per job."""


@dataclass(frozen=True)
class ViewDownload:
    """One job's result downloaded by `bfields view --job`: its folder, size and last view."""

    job: str
    path: Path
    files: int
    size: int
    last_used: float


def _files(folder: Path) -> list[os.stat_result]:
    """The stat of every regular file under `folder` (links not followed)."""
    out = []
    for root, _dirs, names in os.walk(folder):
        for name in names:
            st = os.lstat(os.path.join(root, name))
            if stat.S_ISREG(st.st_mode):
                out.append(st)
    return out


def disk_usage(cache_dir: Path) -> int:
    """Bytes of every regular file under `cache_dir` (0 when it does not exist)."""
    return sum(st.st_size for st in _files(cache_dir))


def view_downloads(cache_dir: Path) -> list[ViewDownload]:
    """Every `view/<job>/` download in `cache_dir`, most recently viewed first."""
    root = cache_dir / VIEW_DIR
    if not root.is_dir():
        return []
    out = []
    for folder in root.iterdir():
        if not folder.is_dir() or folder.is_symlink():
            continue
        stats = _files(folder)
        last = max((st.st_mtime for st in stats), default=folder.stat().st_mtime)
        out.append(ViewDownload(folder.name, folder, len(stats), sum(st.st_size for st in stats), last))
    return sorted(out, key=lambda d: d.last_used, reverse=True)


def remove_download(download: ViewDownload) -> None:
    """Delete one downloaded result (`bfields view --job` downloads it again when asked)."""
    shutil.rmtree(download.path)
