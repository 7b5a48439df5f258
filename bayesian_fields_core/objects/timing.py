"""Wall-clock seconds per named step, so a stage report can say where its time went.

One `with timer("aib"):` per step replaces hand-written `t = perf_counter()` pairs; a step
entered twice adds up.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class StepTimer:
    """`seconds` maps each step's name to its total wall-clock time."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
