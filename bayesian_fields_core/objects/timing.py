"""Wall-clock and process-CPU seconds per named step, so a stage report can say where its time went.

One `with timer("aib"):` per step replaces hand-written `t = perf_counter()` pairs; a step
entered twice adds up. CPU seconds are kept beside wall seconds because on a shared machine the
wall time includes waiting for a core (the CPU time of all the process's threads does not).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class StepTimer:
    """`seconds` maps each step's name to its total wall-clock time, `cpu_seconds` to the process
    CPU time (all threads) spent meanwhile."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.cpu_seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            self.cpu_seconds[name] = self.cpu_seconds.get(name, 0.0) + time.process_time() - cpu
