"""The alignment verdict is cached on the content it depends on, like perception.

Real sample, real check (renders and photos), jobs laid out as `bfields run`'s (the job in its
output folder, the caches in one cache folder with no prefix): a
second job reads the verdict back (the report says `cached`, carries the first run's numbers
and its stage report says so too); changing any input the check reads (the splat transform, one
camera, one compared photo, each declared parameter) misses the cache; the task list, an
undeclared parameter or the folder's location do not.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.checks.alignment import _PACKAGE, CODE_FILES
from bayesian_fields_core.checks.alignment_reports import AlignmentReport
from bayesian_fields_core.job.cache_index import list_entries, prune
from bayesian_fields_core.job.factories import Job, local_job
from bayesian_fields_core.job.stage_table import ALIGNMENT_CACHE
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models
from tests.support.scene_transforms import copy_scene

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"
TASKS = ["get the red cube"]


def make_job(
    scene: Path,
    cache: Path,
    out: Path,
    *,
    tasks: list[str] = TASKS,
    splat_transform: Path | None = None,
    **params: object,
) -> Job:
    """A job laid out as `bfields run`'s: the job in `out`, the caches in `cache`."""
    params_ = PipelineParams(**params)  # type: ignore[arg-type]
    return local_job(scene, out, cache, tasks, params_, load_models(), splat_transform=splat_transform)


def alignment(job: Job) -> AlignmentReport | None:
    """The job's alignment check, on the device its stages would render on."""
    return job.scene.alignment(job.runner.render_device(job.spec.params))


def write_transform(path: Path, shift: float) -> Path:
    """A nerfstudio dataparser transform (splat frame -> camera frame): identity plus a shift."""
    transform = np.eye(4)[:3]
    transform[0, 3] = shift
    path.write_text(json.dumps({"transform": transform.tolist(), "scale": 1.0}))
    return path


@pytest.mark.slow
def test_a_second_run_reads_the_verdict_and_a_prune_drops_it(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    first = alignment(make_job(SAMPLE, cache, tmp_path / "a"))
    assert first is not None and first.passed and not first.cached
    again = make_job(SAMPLE, cache, tmp_path / "b")
    second = alignment(again)
    assert second is not None and second.cached and "(cached)" in second.summary()
    # the stored report, not a new measurement: every number (the check's own seconds included)
    assert second.model_dump(exclude={"cached"}) == first.model_dump(exclude={"cached"})
    key = again.scene.keys.alignment_key()
    assert key.startswith(ALIGNMENT_CACHE.folder) and (cache / key).is_file()
    # the cache index counts it (bfields cache ls) and a prune removes it with its entry
    [entry] = list_entries(LocalStore(cache))
    assert key in entry.keys
    assert prune(LocalStore(cache), max_size=0).files_removed >= 1
    assert not (cache / key).exists()
    third = alignment(make_job(SAMPLE, cache, tmp_path / "c"))
    assert third is not None and not third.cached


@pytest.mark.slow
def test_the_perceive_report_says_the_verdict_was_cached(tmp_path: Path) -> None:
    from bayesian_fields_core.stages.perceive import alignment_summary

    cache = tmp_path / "cache"
    alignment(make_job(SAMPLE, cache, tmp_path / "a"))
    report = alignment(make_job(SAMPLE, cache, tmp_path / "b"))
    assert alignment_summary(report)["cached"] is True


@pytest.mark.slow
def test_a_failed_verdict_is_cached_and_still_refuses(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from bayesian_fields_core.errors import InputError

    cache = tmp_path / "cache"
    caplog.set_level(logging.DEBUG, logger="bayesian_fields_core.job.alignment_cache")
    for out in ("a", "b"):
        job = make_job(SAMPLE, cache, tmp_path / out, alignment_min_score=0.999)
        with pytest.raises(InputError, match="renders of the splat do not match"):
            alignment(job)
    assert [r.getMessage().split()[2] for r in caplog.records] == ["miss", "hit"]
    stored = json.loads(job.spec.cache_store.get_bytes(job.scene.keys.alignment_key()))
    assert stored["passed"] is False and stored["cached"] is False  # `cached` is set on reading


def _key(scene: Path, tmp_path: Path, **kwargs: object) -> str:
    return make_job(scene, tmp_path / "cache", tmp_path / "out", **kwargs).scene.keys.alignment_key()  # type: ignore[arg-type]


CHANGED = {
    "alignment_min_frustum_share": 0.6,
    "alignment_max_extent_ratio": 7.0,
    "alignment_min_score": 0.3,
    "alignment_frames": 3,
    "alignment_max_side": 128,
    "scene_scale": 2.5,
}


@pytest.mark.parametrize("name", ALIGNMENT_CACHE.params)
def test_each_declared_parameter_changes_the_key(tmp_path: Path, name: str) -> None:
    assert _key(SAMPLE, tmp_path) != _key(SAMPLE, tmp_path, **{name: CHANGED[name]})


def test_the_tasks_an_undeclared_parameter_and_the_location_keep_the_key(tmp_path: Path) -> None:
    base = _key(SAMPLE, tmp_path)
    assert _key(SAMPLE, tmp_path, tasks=["something else", "and more"]) == base
    assert _key(SAMPLE, tmp_path, top_k=2, prior=0.2, alignment_check=True) == base
    assert _key(copy_scene(SAMPLE, tmp_path / "moved"), tmp_path) == base


def test_the_transform_changes_the_key(tmp_path: Path) -> None:
    a = _key(SAMPLE, tmp_path, splat_transform=write_transform(tmp_path / "a.json", 0.0))
    b = _key(SAMPLE, tmp_path, splat_transform=write_transform(tmp_path / "b.json", 0.01))
    assert a != b


def test_one_camera_changes_the_key(tmp_path: Path) -> None:
    base = _key(SAMPLE, tmp_path)
    scene = copy_scene(SAMPLE, tmp_path / "camera")
    doc = json.loads((scene / "transforms.json").read_text())
    doc["frames"][7]["transform_matrix"][0][3] += 0.001  # a frame the rendered part does not use
    (scene / "transforms.json").write_text(json.dumps(doc))
    assert _key(scene, tmp_path) != base


@pytest.mark.slow
def test_one_compared_photo_changes_the_key_and_the_verdict_is_recomputed(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    scene = copy_scene(SAMPLE, tmp_path / "photo")
    assert not alignment(make_job(scene, cache, tmp_path / "a")).cached  # type: ignore[union-attr]
    first = sorted((scene / "images").iterdir())[0]  # frame 0 is always compared
    pixels = np.asarray(Image.open(first)).copy()
    pixels[0, 0] ^= 1
    Image.fromarray(pixels).save(first)
    report = alignment(make_job(scene, cache, tmp_path / "b"))
    assert report is not None and not report.cached


def test_the_code_fingerprint_covers_files_that_exist() -> None:
    for name in CODE_FILES:
        path = _PACKAGE / name
        assert path.is_file() or any(path.glob("*.py")), name
