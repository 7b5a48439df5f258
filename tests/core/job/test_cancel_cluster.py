"""A cancel reaches the cluster stage at every step, and a cancelled cluster leaves no result.

Why: the service answered 202 to a cancel during `cluster` and the job still succeeded with a
full result, because the stage only checked for cancellation while replaying primitives, a path
not taken when `fuse` stored them (the usual case). Here the cancel fires on the n-th check, for
every n the stage makes, with the primitives stored by `fuse`.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.errors import CancelledError
from bayesian_fields_core.job.artifacts import PRIMITIVES_KEY, RESULT_PREFIX
from bayesian_fields_core.job.markers import is_done
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.store import LocalStore
from tests.core.conftest import counting_models, make_job

# Slow (the inner loop leaves it out): its fixtures took 5.0 s to set up here (--durations).
pytestmark = pytest.mark.slow


class _Counter:
    """should_cancel that answers True from its (n+1)-th call on (never, with n=None)."""

    def __init__(self, n: int | None = None) -> None:
        self.n, self.calls = n, 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.n is not None and self.calls > self.n


@pytest.fixture(scope="module")
def fused(scene_dir: Path, profile: dict, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A job folder with perceive and fuse done (so the primitives are stored)."""
    root = tmp_path_factory.mktemp("cluster-cancel")
    job = make_job(scene_dir, root / "job", root / "cache", counting_models(profile))
    run_stage("perceive", job)
    run_stage("fuse", job)
    assert job.spec.store.exists(job.spec.key(PRIMITIVES_KEY))
    return root


def _job(fused: Path, scene_dir: Path, profile: dict, cancel: _Counter, name: str):  # noqa: ANN202
    import shutil

    shutil.rmtree(fused / name, ignore_errors=True)
    shutil.copytree(fused / "job", fused / name)
    return make_job(scene_dir, fused / name, fused / "cache", counting_models(profile), should_cancel=cancel)


def _checks(fused: Path, scene_dir: Path, profile: dict) -> int:
    counter = _Counter()
    job = _job(fused, scene_dir, profile, counter, "count")
    run_stage("cluster", job)
    return counter.calls


def test_the_cluster_stage_checks_at_its_boundary_between_steps_and_after_writing(
    fused: Path, scene_dir: Path, profile: dict
) -> None:
    # boundary, start, primitives, scores, edges, AIB, select, kNN, before the write, after it
    assert _checks(fused, scene_dir, profile) >= 8


def test_a_cancel_at_any_check_of_the_cluster_stage_leaves_no_result(
    fused: Path, scene_dir: Path, profile: dict
) -> None:
    total = _checks(fused, scene_dir, profile)
    assert total > 0, "the cluster stage never checks for cancellation"
    for n in range(total):
        cancel = _Counter(n)
        job = _job(fused, scene_dir, profile, cancel, f"cancel-{n}")
        with pytest.raises(CancelledError):
            run_stage("cluster", job)
        assert cancel.calls == n + 1
        assert job.spec.store.list(job.spec.key(RESULT_PREFIX)) == [], (
            f"cancel at check {n + 1} left a result"
        )
        assert not is_done(job.spec, "cluster")


def test_discard_result_removes_a_result_written_before_the_cancel_was_seen(
    fused: Path, scene_dir: Path, profile: dict
) -> None:
    from bayesian_fields_core.job.pipeline import discard_result

    job = _job(fused, scene_dir, profile, _Counter(), "late")
    run_stage("cluster", job)
    assert job.spec.store.list(job.spec.key(RESULT_PREFIX)) and is_done(job.spec, "cluster")
    discard_result(LocalStore(fused / "late"), job.spec.job_prefix)
    assert job.spec.store.list(job.spec.key(RESULT_PREFIX)) == [] and not is_done(job.spec, "cluster")
    assert is_done(job.spec, "fuse")  # earlier stages stay: their outputs are not the result
