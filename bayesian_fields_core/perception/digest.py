"""Content hashes of model files, for model ids and cache fingerprints.

Model ids must change when the weights change (a calibration fitted for one checkpoint is wrong for
another, and cached embeddings from old weights must not be reused) but must not depend on where
the operator put the files. Hashing a 600 MB checkpoint takes about a second, so results are
memoised per (path, size, mtime).
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Iterable
from pathlib import Path

from bayesian_fields_core.errors import ModelError


@functools.lru_cache(maxsize=256)
def _sha256_cached(path: str, size: int, mtime_ns: int) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def file_sha256(path: str | Path) -> str:
    """Hex sha256 of a file's bytes (memoised while the file's size and mtime are unchanged)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise ModelError(f"{p}: cannot read model file ({exc.strerror or exc})") from exc
    return _sha256_cached(str(p.resolve()), st.st_size, st.st_mtime_ns)


def files_digest(paths: Iterable[str | Path], length: int = 12) -> str:
    """Short combined hash of several files' contents (order-independent of the paths' folders)."""
    combined = hashlib.sha256()
    for p in paths:
        combined.update(file_sha256(p).encode())
    return combined.hexdigest()[:length]
