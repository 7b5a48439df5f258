"""The stage table is the one place a stage is declared, and it says what keys each cache."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from bayesian_fields_core.job.cache_keys import CacheKeys
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.stage_table import (
    STAGE_TABLE,
    STAGES,
    VISIBILITY_CACHE,
    stage,
)
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "samples" / "tabletop"


def test_table_rows_are_complete() -> None:
    assert STAGES == ("perceive", "fuse", "cluster")
    assert sum(spec.weight for spec in STAGE_TABLE) == pytest.approx(1.0)
    for spec in STAGE_TABLE:
        assert callable(spec.load())
        assert spec.queue in {"gpu", "cpu"}
        assert stage(spec.name) is spec


def keys(tmp_path: Path, **params: object) -> CacheKeys:
    """The cache keys of a job on the sample under `params`."""
    job = local_job(SAMPLE, tmp_path, tmp_path, ["get the red cube"], PipelineParams(**params), load_models())
    return job.scene.keys


@pytest.mark.parametrize("name", VISIBILITY_CACHE.params)
def test_a_declared_parameter_changes_the_visibility_key(tmp_path: Path, name: str) -> None:
    changed = {
        "depth_source": "expected",
        "scene_scale": 3.0,
        "depth_tolerance": 0.123,
        "depth_tolerance_scene": 0.05,
        "depth_tolerance_relative": 0.321,
    }[name]
    assert keys(tmp_path).visibility_key(0) != keys(tmp_path, **{name: changed}).visibility_key(0)


@pytest.mark.parametrize("name", ["prior", "top_k", "crop_batch_size", "knn_k"])
def test_an_undeclared_parameter_keeps_every_cache_key(tmp_path: Path, name: str) -> None:
    changed = {"prior": 0.2, "top_k": 2, "crop_batch_size": 7, "knn_k": 11}[name]
    a, b = keys(tmp_path), keys(tmp_path, **{name: changed})
    assert a.visibility_key(0) == b.visibility_key(0)
    assert a.perception_key(0) == b.perception_key(0)


@pytest.mark.parametrize(
    "pattern",
    [
        "_STAGE_FUNCTIONS",
        "NOT_IN_ANY_CACHE_KEY",
        "STAGE_QUEUE_ROLE",
        '_make_stage_task("',
        "zip(STAGES",
        'STAGES = ("perceive"',
        '"bfields.stage.perceive"',
    ],
)
def test_the_old_declarations_are_gone(pattern: str) -> None:
    found = subprocess.run(
        ["git", "grep", "-n", "-F", pattern, "--", "bayesian_fields_core", "services"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert found.stdout == "", found.stdout
