"""The same capture in other units, axes and origin gives the same objects and the same answers.

COLMAP's units and frame are arbitrary, so a scene and its copy under a similarity (scale 0.01,
2.5 or 100, a rotation and a translation, applied to the splat and the cameras together) are one
capture. The whole pipeline runs on both (real renders, real masks, the bundled tiny CLIP) and the
results must agree: the partition of the Gaussians into objects up to relabelling (>= 99% of the
Gaussians in matched objects) and every task's ranked answers. Before every length followed the
scene scale, 7 of the sample's 8 tasks changed their answers at scale 2.5.

Runs on the bundled sample (every other frame, to keep the test minutes, not hours, on a CPU) and
on a small scene of the synthetic capture suite (handheld walk, occluders, striped textures).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from bayesian_fields_core.eval.synthetic.generate import generate_scene
from bayesian_fields_core.eval.synthetic.spec import SceneSpec, capture_layouts
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.task_list import load_tasks
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import Models, load_models
from bayesian_fields_core.results.format import Result
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.similarity import Similarity
from tests.support.scene_transforms import similar_scene

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "samples" / "tabletop"
SCALES = (0.01, 2.5, 100.0)
MIN_SHARED = 0.99


def _rotation() -> np.ndarray:
    """40 degrees about an oblique axis (Rodrigues), so no coordinate axis is preserved."""
    axis = np.array([0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.deg2rad(40.0)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def similarity(scale: float) -> Similarity:
    """x -> scale R x + t, with the shift in the new units (so it is a comparable move at each scale)."""
    return Similarity(scale, _rotation(), scale * np.array([1.2, -0.7, 0.4]))


def run(
    folder: Path, root: Path, cache: Path, models: Models, tasks: list[str], params: PipelineParams
) -> Result:
    """The whole pipeline on `folder`; the scene cache is shared, so perception (which only sees
    the photos, identical in every copy) runs once per scene."""
    job = local_job(
        folder, root, cache, tasks, params, models, job_prefix="job/", cache_prefix="scene/cache/"
    )
    run_job(job)
    return read_result(job.spec.store, job.spec.key(RESULT_PREFIX))


def matching(a: np.ndarray, b: np.ndarray) -> tuple[float, dict[int, int]]:
    """(share of Gaussians in matched objects, object of `a` -> its match in `b`) for two (N,)
    object-id maps (-1 = none, matched to none). The one-to-one matching that keeps the most
    Gaussians (Hungarian), so a relabelled but identical partition scores 1.0."""
    la, ia = np.unique(a, return_inverse=True)
    lb, ib = np.unique(b, return_inverse=True)
    table = np.zeros((len(la), len(lb)), dtype=np.int64)
    np.add.at(table, (ia, ib), 1)
    rows, cols = linear_sum_assignment(table, maximize=True)
    share = float(table[rows, cols].sum()) / len(a)
    return share, {int(la[r]): int(lb[c]) for r, c in zip(rows, cols, strict=True)}


def answers(result: Result, relabel: dict[int, int] | None = None) -> dict[str, list[int]]:
    """Each task's ranked object ids (mapped through `relabel`), and 'not found' as no ids."""
    ids = {task: [o.object_id for o in result.selections.get(task, [])] for task in result.tasks}
    if relabel is None:
        return ids
    return {task: [relabel.get(i, -2) for i in chosen] for task, chosen in ids.items()}


def check_invariance(reference: Result, moved: Result, sim: Similarity) -> None:
    share, relabel = matching(reference.object_ids, moved.object_ids)
    assert share >= MIN_SHARED, f"only {share:.4f} of the Gaussians keep their object at scale {sim.scale}"
    assert answers(reference, relabel) == answers(moved), f"answers changed at scale {sim.scale}"
    assert set(reference.not_found) == set(moved.not_found)
    print(
        f"scale {sim.scale:g}: {share:.4%} of {len(moved.object_ids)} Gaussians keep their object; answers equal"
    )
    ref_scale, new_scale = reference.scene_scale["value"], moved.scene_scale["value"]
    assert new_scale == pytest.approx(sim.scale * ref_scale, rel=1e-5)
    for task in reference.tasks:  # the answers are where the moved scene puts them
        for a, b in zip(reference.selections[task], moved.selections[task], strict=True):
            np.testing.assert_allclose(sim.points(a.centroid), b.centroid, atol=1e-3 * new_scale)
            assert b.num_gaussians == a.num_gaussians


@pytest.fixture(scope="module")
def models() -> Models:
    return load_models()


@pytest.fixture(scope="module")
def capture_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small scene of the capture suite: its first layout (walk, occluders, stripes, labels,
    SH degree 1) with fewer frames, pixels and Gaussians."""
    base = capture_layouts()[0].model_dump()
    small = {
        "n_frames": 8,
        "width": 160,
        "height": 120,
        "object_density": 6000.0,
        "table_density": 900.0,
        "room_density": 60.0,
    }
    spec = SceneSpec.model_validate({**base, **small})
    return generate_scene(tmp_path_factory.mktemp("capture-scene"), spec)


SCENES = {
    "sample": (lambda request: SAMPLE, PipelineParams(frame_stride=2, previews=False, export_ply=False)),
    "capture": (
        lambda request: request.getfixturevalue("capture_scene"),
        PipelineParams(previews=False, export_ply=False),
    ),
}


@pytest.fixture(scope="module", params=sorted(SCENES))
def reference(request: pytest.FixtureRequest, models: Models, tmp_path_factory: pytest.TempPathFactory):
    """(scene folder, params, cache folder, tasks, result on the untouched scene) per scene."""
    folder_of, params = SCENES[request.param]
    folder = folder_of(request)
    tasks = load_tasks(folder / "tasks.yaml")
    cache = tmp_path_factory.mktemp(f"{request.param}-cache")
    result = run(folder, tmp_path_factory.mktemp(f"{request.param}-ref"), cache, models, tasks, params)
    return folder, params, cache, tasks, result


@pytest.mark.parametrize("scale", SCALES)
def test_a_similar_scene_gives_the_same_objects_and_answers(
    reference, scale: float, models: Models, tmp_path: Path
) -> None:
    folder, params, cache, tasks, result = reference
    assert sum(len(objs) for objs in result.selections.values()) > 0  # something to compare
    sim = similarity(scale)
    moved = similar_scene(folder, tmp_path / "scene", sim)
    check_invariance(result, run(moved, tmp_path / "out", cache, models, tasks, params), sim)


def test_an_absolute_tolerance_is_not_scaled(models: Models, tmp_path: Path) -> None:
    """The override stays absolute: depth_tolerance set by hand is the tolerance used, in the
    scene's units, whatever its scale (the run records the lengths it used)."""
    params = PipelineParams(frame_stride=10, previews=False, export_ply=False, depth_tolerance=0.05)
    tasks = load_tasks(SAMPLE / "tasks.yaml")
    moved = similar_scene(SAMPLE, tmp_path / "scene", similarity(2.5))
    result = run(moved, tmp_path / "out", tmp_path / "cache", models, tasks, params)
    assert result.scene_scale["lengths"]["depth_tolerance"] == 0.05
    assert result.scene_scale["lengths"]["render_near"] == pytest.approx(2.5 * 0.005 * 1.849, rel=1e-3)
