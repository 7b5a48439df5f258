"""Fewer threads for work made of many small steps: one OpenBLAS thread for the cluster stage's
box search (`single_blas_thread`), a set number of torch intra-op threads for previews
(`torch_threads`). Both limit process-wide settings for the length of a block and restore them.

OpenBLAS, why: the box search multiplies a few thousand points by 3x3 frames and 64 directions per object,
100+ objects per result. OpenBLAS splits each such product over all cores and its threads
busy-wait between calls, so on 2 cores the boxes cost 2.3x the CPU they need (0.39 against
0.17 s at the scale bench), and the per-object worker threads of `clustering._per_object` then
compete with BLAS's own. OpenBLAS partitions a product's output, never the sum behind one entry,
so the numbers do not depend on the thread count (the reference test checks the boxes).

How: the OpenBLAS copies loaded in this process (numpy's and scipy's, found in `/proc/self/maps`)
are set to one thread for the duration and restored after. Where there is no `/proc` or no
OpenBLAS (MKL, Accelerate), nothing changes. The setting is per library, hence process-wide:
another thread's BLAS call meanwhile also runs on one thread, which costs it time, not results.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

_SUFFIXES = ("64_", "")  # ILP64 builds (numpy's) append 64_, LP64 builds (scipy's) do not
_PREFIXES = ("scipy_openblas", "openblas")

_Controls = tuple[Callable[[], int], Callable[[int], None]]


def _controls(path: str) -> _Controls | None:
    """(get_num_threads, set_num_threads) of the OpenBLAS at `path`, or None."""
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return None
    for prefix in _PREFIXES:
        for suffix in _SUFFIXES:
            getter = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
            setter = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
            if getter is not None and setter is not None:
                getter.restype = ctypes.c_int
                setter.argtypes = [ctypes.c_int]
                return getter, setter
    return None


def loaded_openblas() -> list[_Controls]:
    """Thread controls of every OpenBLAS mapped into this process (empty where unknown)."""
    maps = Path("/proc/self/maps")
    try:
        lines = maps.read_text().splitlines()
    except OSError:
        return []
    paths = sorted({line.split()[-1] for line in lines if "openblas" in line.lower() and "/" in line})
    return [c for c in (_controls(p) for p in paths) if c is not None]


@contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the block with every loaded OpenBLAS on one thread, restoring the counts after."""
    controls = loaded_openblas()
    previous = [get() for get, _ in controls]
    for _, set_threads in controls:
        set_threads(1)
    try:
        yield
    finally:
        for (_, set_threads), count in zip(controls, previous, strict=True):
            set_threads(count)


@contextmanager
def torch_threads(count: int | None) -> Iterator[None]:
    """Run the block with `count` torch intra-op threads (None: leave the setting alone),
    restoring the previous count after. Why: torch ops of a few hundred small steps end each in a
    barrier where idle threads spin, so on a shared CPU more threads cost CPU, not time saved."""
    import torch

    previous = torch.get_num_threads()
    if count is not None:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
