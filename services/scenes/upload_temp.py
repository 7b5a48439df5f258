"""Remove the upload temp folders that an API process killed mid-request leaves behind.

An upload is received into a local temp folder, validated, then copied to the bucket. A SIGKILL
(OOM killer, node loss) mid-request leaves the folder ``bfields-upload-<pid>-*`` /
``bfields-complete-<pid>-*`` of a dead process. Each API process removes such folders at start and
every BFIELDS_ORPHAN_SWEEP_INTERVAL_S once their owner is dead and their last write is older than
BFIELDS_ORPHAN_MAX_AGE_S, so an upload in progress is never touched. What such a kill leaves in the
bucket is the control process's to remove (`bucket_sweep`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

log = logging.getLogger(__name__)

TEMP_KINDS = ("upload", "complete")


def upload_workdir(kind: str) -> Path:
    """A new temp folder for one request, named after this process so the sweeper can tell a
    live owner from a dead one: ``<tmp>/bfields-<kind>-<pid>-<random>``."""
    return Path(tempfile.mkdtemp(prefix=f"bfields-{kind}-{os.getpid()}-"))


@contextlib.contextmanager
def workdir(kind: str) -> Iterator[Path]:
    """`upload_workdir` for the ``with`` body, removed when it ends whatever happened."""
    folder = upload_workdir(kind)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _owner_pid(name: str) -> int | None:
    parts = name.split("-")  # bfields, kind, pid, random
    return int(parts[2]) if len(parts) >= 4 and parts[2].isdigit() else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _last_write(folder: Path) -> float:
    newest = folder.lstat().st_mtime
    for dirpath, dirs, files in os.walk(folder):
        for name in (*dirs, *files):
            with contextlib.suppress(OSError):
                newest = max(newest, os.lstat(os.path.join(dirpath, name)).st_mtime)
    return newest


def sweep_temp(root: Path, max_age_s: float, *, now: float | None = None) -> list[str]:
    """Delete upload temp folders under `root` whose owner is not alive and whose last write is
    older than `max_age_s`; returns their names."""
    now = time.time() if now is None else now
    removed = []
    for kind in TEMP_KINDS:
        for folder in root.glob(f"bfields-{kind}-*"):
            if not folder.is_dir() or folder.is_symlink():
                continue
            pid = _owner_pid(folder.name)
            if pid is not None and pid != os.getpid() and _alive(pid):
                continue
            if pid == os.getpid():
                continue  # this process's own request is still running
            try:
                if now - _last_write(folder) < max_age_s:
                    continue
            except FileNotFoundError:
                continue
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder.name)
    return removed


class Sweeper:
    """Sweeps this API process's upload temp folders at start and every `interval_s`, in a daemon
    thread. (The bucket's part, `sweep_bucket`, is the control process's: one sweep per
    deployment, not one per API replica.)"""

    def __init__(self, max_age_s: float, interval_s: float, temp_root: Path | None = None) -> None:
        self.max_age_s = max_age_s
        self.interval_s = interval_s
        self.temp_root = temp_root or Path(tempfile.gettempdir())
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def sweep_once(self) -> None:
        removed = sweep_temp(self.temp_root, self.max_age_s)
        if removed:
            log.warning("orphan sweep: removed %d upload temp folders: %s", len(removed), removed)

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.sweep_once()
            except Exception:  # keep sweeping whatever one pass hit
                log.exception("orphan sweep failed")
            self._stop.wait(self.interval_s)

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="bf-orphan-sweep", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
