"""Previews and per-task exports of format 1.2, on the bundled sample scene with its ground-truth
objects as the result: the preview is rendered from a view that sees the task's top object, the
object is tinted red where it projects, the legend strip is there, the contact sheet tiles every
task, summary.json lists it all, and the per-task .ply colours the task's objects by rank and
carries `object_id`."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.geometry.obb import minimum_obb
from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results import FORMAT_VERSION, Result, SelectedObject, read_result, write_result
from bayesian_fields_core.results.colours import BACKGROUND_GREY, rank_colour
from bayesian_fields_core.results.previews import best_view
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.ply import read_ply

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"
CONE, CUBE = 9, None  # gt instance of "get the orange cone"; the cube's id is looked up below


@pytest.fixture(scope="module")
def scene():
    return load_scene(SAMPLE)


@pytest.fixture(scope="module")
def gt_result(scene) -> Result:
    ids = np.load(SAMPLE / "gt_gaussians.npz")["instance_ids"].astype(np.int64)
    gt = json.loads((SAMPLE / "gt.json").read_text())
    cube = next(i["id"] for i in gt["instances"] if i["name"] == "cyan cube")
    n_obj = int(ids.max()) + 1
    tasks = ["get the orange cone", "get the cyan cube", "pick up the red lamp"]
    probs = np.full((n_obj, len(tasks) + 1), 0.05, dtype=np.float32)
    probs[CONE, 0] = probs[cube, 1] = 0.9
    probs /= probs.sum(1, keepdims=True)

    def obj(i: int, p: float) -> SelectedObject:
        pts = scene.gaussians.means[ids == i]
        return SelectedObject(i, p, len(pts), pts.mean(0), minimum_obb(pts))

    selections = {tasks[0]: [obj(CONE, 0.9), obj(cube, 0.2)], tasks[1]: [obj(cube, 0.9)], tasks[2]: []}
    return Result(tasks=tasks, object_ids=ids, probabilities=probs, selections=selections)


def _project(frame, points: np.ndarray, scale: float) -> np.ndarray:
    cam = (frame.world_to_camera[:3, :3] @ points.T).T + frame.world_to_camera[:3, 3]
    uv = (frame.K @ cam.T).T
    return uv[:, :2] / uv[:, 2:] * scale


@pytest.mark.slow
def test_previews_and_task_exports(tmp_path: Path, scene, gt_result: Result) -> None:
    store = LocalStore(tmp_path)
    sizes = write_result(
        store, "r/", gt_result, gaussians=scene.gaussians, frames=scene.frames, preview_max_side=240,
        scene={"folder": str(SAMPLE)},
    )  # fmt: skip
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["format_version"] == FORMAT_VERSION == "1.6"
    assert summary["scene"] == {"folder": str(SAMPLE)}
    previews = summary["previews"]
    assert [p["task"] for p in previews["tasks"]] == gt_result.tasks
    assert previews["contact_sheet"] == "previews/contact_sheet.png"
    assert all(p["file"] in sizes for p in previews["tasks"])

    # the cone's preview: rendered from the frame that sees it best, red where the cone projects
    cone_pts = scene.gaussians.means[gt_result.object_ids == CONE]
    entry = previews["tasks"][0]
    index = best_view(scene.frames, cone_pts)
    frame = scene.frames[index]
    assert entry["frame"] == frame.name
    image = np.asarray(Image.open(tmp_path / "r" / entry["file"]).convert("RGB")).astype(int)
    scale = 240 / max(frame.width, frame.height)
    h, w = round(frame.height * scale), round(frame.width * scale)
    left = (image.shape[1] - w) // 2  # the legend strip is at least 320 px wide; the render is centred
    render, legend = image[:h, left : left + w], image[h:]
    assert legend.shape[0] > 40 and legend.mean() < 80  # the dark legend strip with text
    red = (render[..., 0] > 170) & (render[..., 1] < 120) & (render[..., 2] < 110)
    assert red.sum() > 30, red.sum()
    uv = _project(frame, cone_pts, scale)
    ys, xs = np.nonzero(red)
    assert np.hypot(xs.mean() - uv[:, 0].mean(), ys.mean() - uv[:, 1].mean()) < 15
    # the task with no object renders without any rank colour
    empty = np.asarray(Image.open(tmp_path / "r" / previews["tasks"][2]["file"]).convert("RGB")).astype(int)
    assert ((empty[..., 0] > 170) & (empty[..., 1] < 120) & (empty[..., 2] < 110)).sum() == 0

    sheet = Image.open(io.BytesIO((tmp_path / "r" / previews["contact_sheet"]).read_bytes()))
    assert sheet.width >= 2 * 320 and sheet.height >= 2 * 100  # 3 tasks -> 2 x 2 grid

    # per-task splat: the task's objects in rank colour, the rest grey, object_id on every vertex
    assert summary["exports"]["tasks"][gt_result.tasks[0]] == "exports/tasks/task_00.ply"
    task_ply = read_ply(tmp_path / "r" / "exports" / "tasks" / "task_00.ply")
    np.testing.assert_array_equal(task_ply.extra["object_id"], gt_result.object_ids)
    rgb = 0.5 + SH_C0 * task_ply.sh[:, 0, :]
    np.testing.assert_allclose(
        rgb[gt_result.object_ids == CONE], np.tile(rank_colour(0), (len(cone_pts), 1)), atol=1e-5
    )
    second = gt_result.selections[gt_result.tasks[0]][1].object_id
    np.testing.assert_allclose(rgb[gt_result.object_ids == second].mean(0), rank_colour(1), atol=1e-5)
    rest = ~np.isin(gt_result.object_ids, [CONE, second])
    np.testing.assert_allclose(rgb[rest], BACKGROUND_GREY, atol=1e-5)
    scene_ply = read_ply(tmp_path / "r" / "exports" / "scene_objects.ply")
    np.testing.assert_array_equal(scene_ply.extra["object_id"], gt_result.object_ids)
    assert read_result(store, "r/").tasks == gt_result.tasks  # still a readable result


def test_no_previews_without_frames(tmp_path: Path, scene, gt_result: Result) -> None:
    store = LocalStore(tmp_path)
    write_result(store, "r/", gt_result, gaussians=scene.gaussians, export_ply=False)
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["previews"] == {"tasks": [], "contact_sheet": None}
    assert not (tmp_path / "r" / "previews").exists()


@pytest.mark.slow
def test_preview_settings_match_the_renderer_defaults_and_restore_threads(scene, gt_result: Result) -> None:
    """The previews' own rasterisation (8-px tiles, faint-tile cull, one thread) gives the images
    of the renderer's defaults up to a rare grey level, picks the same views, and leaves torch's
    thread count as it found it."""
    import torch

    from bayesian_fields_core.render.output import RasterSettings
    from bayesian_fields_core.results.previews import render_previews

    before = torch.get_num_threads()
    fast = render_previews(gt_result, scene.gaussians, scene.frames, max_side=160)
    assert torch.get_num_threads() == before
    ref = render_previews(gt_result, scene.gaussians, scene.frames, max_side=160, settings=RasterSettings(),
                          threads=None)  # fmt: skip
    for a, b in zip(fast, ref, strict=True):
        assert a.frame == b.frame
        pa = np.asarray(Image.open(io.BytesIO(a.png)).convert("RGB")).astype(int)
        pb = np.asarray(Image.open(io.BytesIO(b.png)).convert("RGB")).astype(int)
        d = np.abs(pa - pb)
        assert d.max() <= 2 and d.mean() < 0.01
