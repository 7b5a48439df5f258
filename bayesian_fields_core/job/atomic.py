"""Temp files for atomic writes (temp + rename) that end up with the mode any new file gets.

A result is written beside its destination and renamed into place, so a crash never leaves half
a file. `tempfile.mkstemp` makes that temp file 0600 whatever the umask (it is meant for secrets),
and the rename keeps the mode: every result file was readable by its owner only, so a robot
process under another user or a web server could not read a result. Here the temp file is
created with `0o666` and the process's umask (and a folder's default ACL, where one is set)
applied by the kernel, exactly as `open(path, "w")` does: 0644 under umask 022, 0640 under 027.
No umask is read or set, so there is no window where another thread runs under a changed umask.

Every atomic writer of the library and the service (`LocalStore`, the S3 store's downloads, the
client's `bfields fetch`) takes its temp file from `atomic_temp`.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

NEW_FILE_MODE = 0o666
"""What `open()` asks for; the umask takes away from it."""

_ATTEMPTS = 100


def atomic_temp(folder: Path, *, prefix: str = ".tmp-", suffix: str = "") -> tuple[int, Path]:
    """A new, empty file in `folder` (same file system as the destination, so the rename is
    atomic) open for writing: `(fd, path)` like `tempfile.mkstemp`, but with the mode the umask
    gives any new file. The caller writes through `fd`, then `os.replace(path, dest)`, and
    unlinks `path` on failure."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    for _ in range(_ATTEMPTS):
        path = Path(folder) / f"{prefix}{secrets.token_hex(6)}{suffix}"
        try:
            return os.open(path, flags, NEW_FILE_MODE), path
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name in {folder} after {_ATTEMPTS} tries")
