"""What runs a job: its models, where it reports progress, how it learns of a cancel, and how it
shares cache filling with concurrent jobs.

These are the parts of a job that differ between the CLI (a progress bar, no cancel, `NoFlight`)
and a worker (Redis progress and cancel flag, a Redis flight); a stage calls them without asking
which it has.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from bayesian_fields_core.errors import CancelledError
from bayesian_fields_core.job.flight import Flight, NoFlight
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models

ProgressFn = Callable[[str, float], None]
"""``progress(stage, fraction)``, fraction in [0, 1]."""
CancelFn = Callable[[], bool]
"""True once the job should stop (checked between frames and steps)."""


def no_progress(stage: str, fraction: float) -> None:
    """The default progress report: none."""
    return None


def never_cancel() -> bool:
    """The default cancel flag: never raised."""
    return False


@dataclass(frozen=True)
class Runner:
    """The models, callbacks and flight a job's stages run with.

    flight: how concurrent jobs on one scene share the filling of its caches (`flight.Flight`;
    the CLI's `NoFlight`, a worker's Redis lock).
    """

    models: Models
    progress: ProgressFn = no_progress
    should_cancel: CancelFn = never_cancel
    flight: Flight = field(default_factory=NoFlight)

    def check_cancel(self) -> None:
        """Raise `CancelledError` when the job has been cancelled."""
        if self.should_cancel():
            raise CancelledError("job cancelled")

    def render_device(self, params: PipelineParams) -> str:
        """Where the splat is rendered (the alignment check, fuse's depth): the job's device,
        else the models' device when one was forced (a worker's), else the CPU."""
        return params.device or self.models.device or "cpu"
