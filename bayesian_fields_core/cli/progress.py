"""A progress bar per stage for the CLI, fed by the pipeline's `progress(stage, fraction)` callback."""

from __future__ import annotations

from types import TracebackType

from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TaskProgressColumn, TextColumn, TimeElapsedColumn

from bayesian_fields_core.job.stage_table import STAGES


class StageProgress:
    """Context manager showing one rich progress bar per pipeline stage."""

    def __init__(self, console: Console, *, enabled: bool = True) -> None:
        self._progress = Progress(
            TextColumn("{task.description:<9}"),
            BarColumn(),
            TaskProgressColumn(),
            TimeElapsedColumn(),
            console=console,
            disable=not enabled,
        )
        self._tasks: dict[str, TaskID] = {}

    def __enter__(self) -> StageProgress:
        self._progress.__enter__()
        for stage in STAGES:
            self._tasks[stage] = self._progress.add_task(stage, total=1.0, start=False)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._progress.__exit__(exc_type, exc, tb)

    def update(self, stage: str, fraction: float) -> None:
        task = self._tasks.get(stage)
        if task is None:
            return
        self._progress.start_task(task)
        self._progress.update(task, completed=min(max(fraction, 0.0), 1.0))
