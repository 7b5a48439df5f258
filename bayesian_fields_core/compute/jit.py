"""numba compilation for the few loops that cannot be vectorised (sequential greedy merging,
pair sweeps whose output size is unknown up front)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

from numba import njit

_F = TypeVar("_F", bound=Callable[..., object])

#: Every function `compiled` has wrapped (numba dispatchers), for `is_cached`.
KERNELS: list[Any] = []


def compiled(fn: _F) -> _F:
    """`njit` with numba's on-disk cache (compiling takes seconds, loading milliseconds), or
    without it where no cache location is writable (a read-only image with no NUMBA_CACHE_DIR):
    numba refuses to import a cached function there, and compiling per process still works.
    Kernels release the GIL (`nogil`), so threads can run them side by side (the per-object box
    search of the cluster stage does)."""
    try:
        kernel = njit(cache=True, nogil=True)(fn)
    except RuntimeError as err:
        if "cannot cache" not in str(err):
            raise
        kernel = njit(nogil=True)(fn)
    KERNELS.append(kernel)
    return cast(_F, kernel)  # a numba Dispatcher, called like the function it wraps


def is_cached(kernel: Any) -> bool | None:
    """Whether calling `kernel` will not compile it: True when this process compiled it already
    or numba's on-disk cache holds a current build of it (an index whose source stamp matches);
    False when it must compile; None when it cannot tell (numba's cache internals moved)."""
    if kernel.signatures:
        return True
    cache = getattr(kernel, "_cache", None)
    if cache is None or not getattr(cache, "_enabled", True):
        return False  # no disk cache: every process compiles
    try:
        return bool(cache._cache_file._load_index())  # {} when absent or stale
    except (AttributeError, OSError, EOFError, ValueError):
        return None
