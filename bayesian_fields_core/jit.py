"""numba compilation for the few loops that cannot be vectorised (sequential greedy merging,
pair sweeps whose output size is unknown up front)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from numba import njit

_F = TypeVar("_F", bound=Callable[..., object])


def compiled(fn: _F) -> _F:
    """`njit` with numba's on-disk cache (compiling takes seconds, loading milliseconds), or
    without it where no cache location is writable (a read-only image with no NUMBA_CACHE_DIR):
    numba refuses to import a cached function there, and compiling per process still works.
    Kernels release the GIL (`nogil`), so threads can run them side by side (the per-object box
    search of the cluster stage does)."""
    try:
        return njit(cache=True, nogil=True)(fn)
    except RuntimeError as err:
        if "cannot cache" not in str(err):
            raise
        return njit(nogil=True)(fn)
