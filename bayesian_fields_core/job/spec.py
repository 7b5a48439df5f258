"""What a job is: where its artifacts and caches go, its tasks and its parameters; plain data.

A `JobSpec` holds no scene, no model and no callback, so it can be built, compared and logged
without loading anything. The scene it runs on is a `JobScene` (`job/job_scene.py`) and what
runs it is a `Runner` (`job/runner.py`); `job/factories.py` builds the three together for the
two places a job runs (a local folder, a store).
"""

from __future__ import annotations

from dataclasses import dataclass

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.params import PipelineParams


def as_prefix(prefix: str) -> str:
    """`prefix` as a key prefix: "" stays "", anything else ends with "/"."""
    return prefix if not prefix or prefix.endswith("/") else prefix + "/"


@dataclass(frozen=True)
class JobSpec:
    """One job, as data.

    store / job_prefix: where this job's artifacts go (``stages/<name>.json`` marks a finished
    stage, ``result/`` holds the result); `key` names them.
    tasks: the task texts, in the order the result lists them (not empty, no duplicates).
    cache_store / cache_prefix: where the task-independent caches live (``perception/``,
    ``visibility/``, ``alignment/``, ``index/`` below the prefix). Cache keys are content digests,
    so one cache can serve every scene (the CLI's ``~/.cache/bfields``, prefix ""); a job in a
    store keeps them beside its scene (``<scene prefix>cache/``).
    """

    store: Store
    job_prefix: str
    tasks: tuple[str, ...]
    params: PipelineParams
    cache_store: Store
    cache_prefix: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "job_prefix", as_prefix(self.job_prefix))
        object.__setattr__(self, "cache_prefix", as_prefix(self.cache_prefix))
        if not self.tasks:
            raise InputError("the task list is empty", source="tasks")
        if len(set(self.tasks)) != len(self.tasks):
            raise InputError("the task list has duplicates", source="tasks")

    def key(self, name: str) -> str:
        """The store key of this job's artifact `name` (`artifacts` names them)."""
        return self.job_prefix + name
