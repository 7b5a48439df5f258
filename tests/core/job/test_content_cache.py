"""The perception and visibility caches are keyed on content, not on where or when files are.

Each test edits a copy of the tiny scene the way a user would (tasks.yaml in the folder, outputs
inside it, folder moved or copied, one image changed or dropped, another profile) and re-runs it
on a cache primed once, counting calls into the real models. The jobs are built as the CLI builds
its own (`job.factories.local_job`), and one test goes through `bfields run` itself and reads its
report line.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.params import PipelineParams
from tests.core.conftest import N_FRAMES, OTHER_TASKS, TASKS, counting_models

# Slow (the inner loop leaves it out): its fixtures took 3.4 s to set up here (--durations).
pytestmark = pytest.mark.slow


def _run(
    scene: Path,
    out: Path,
    cache: Path,
    profile: dict[str, Any],
    tasks: list[str] = TASKS,
    params: PipelineParams | None = None,
):
    models = counting_models(profile)
    job = local_job(scene, out, cache, list(tasks), params or PipelineParams(), models)
    return run_job(job, force=True), models.counts


@pytest.fixture(scope="module")
def primed(scene_dir: Path, profile: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A cache filled by one run of a copy of the scene (the folder each test then copies)."""
    root = tmp_path_factory.mktemp("content-cache")
    scene = root / "scene"
    shutil.copytree(scene_dir, scene)
    reports, counts = _run(scene, root / "out", root / "cache", profile)
    assert reports["perceive"]["frames_computed"] == N_FRAMES
    # every frame segmented; its crops encoded in batches pooled across frames (crop_batch_size)
    assert (
        counts["segment"] == N_FRAMES and counts["encode_images"] == reports["perceive"]["encoder_calls"] > 0
    )
    return {"scene": scene, "cache": root / "cache", "scale": reports["fuse"]["scene_scale"]["value"]}


def _assert_nothing_recomputed(reports: dict, counts: Any) -> None:
    assert reports["perceive"]["frames_computed"] == 0
    assert reports["perceive"]["frames_cached"] == N_FRAMES
    assert counts["encode_images"] == 0 and counts["segment"] == 0
    assert counts["segmenter_built"] == 0
    assert reports["fuse"]["frames_rendered"] == 0


def test_tasks_yaml_and_out_inside_the_scene_reuse_the_cache(
    primed: dict, profile: dict, tmp_path: Path
) -> None:
    scene = tmp_path / "scene"
    shutil.copytree(primed["scene"], scene)
    (scene / "tasks.yaml").write_text("\n".join(f"- {t}" for t in OTHER_TASKS) + "\n")
    (scene / "out-old").mkdir()
    (scene / "out-old" / "summary.json").write_text("{}")  # a previous run's output in the folder
    reports, counts = _run(scene, scene / "out", primed["cache"], profile, OTHER_TASKS)
    _assert_nothing_recomputed(reports, counts)
    assert counts["encode_texts"] == 1  # only the new tasks were encoded
    # And once more, now that `out/` (with its .ply exports) sits inside the scene folder.
    (scene / "tasks.yaml").write_text("- red chair\n")
    reports, counts = _run(scene, scene / "out2", primed["cache"], profile, ["red chair"])
    _assert_nothing_recomputed(reports, counts)


@pytest.mark.parametrize("how", ["moved", "copied"])
def test_moved_or_copied_scene_reuses_the_cache(
    primed: dict, profile: dict, tmp_path: Path, how: str
) -> None:
    first = tmp_path / "a" / "scene"
    shutil.copytree(primed["scene"], first)
    if how == "moved":
        target = tmp_path / "elsewhere" / "renamed"
        target.parent.mkdir()
        shutil.move(first, target)
        assert not first.exists()
    else:
        target = tmp_path / "b" / "copy"
        shutil.copytree(first, target)  # new inodes, new modification times
    reports, counts = _run(target, tmp_path / "out", primed["cache"], profile)
    _assert_nothing_recomputed(reports, counts)


def test_one_changed_image_recomputes_one_frame(primed: dict, profile: dict, tmp_path: Path) -> None:
    scene = tmp_path / "scene"
    shutil.copytree(primed["scene"], scene)
    path = sorted((scene / "images").glob("*.png"))[2]
    pixels = np.array(Image.open(path))
    pixels[:8, :8] = 255 - pixels[:8, :8]
    Image.fromarray(pixels).save(path)
    reports, counts = _run(scene, tmp_path / "out", primed["cache"], profile)
    assert reports["perceive"]["frames_computed"] == 1
    assert reports["perceive"]["frames_cached"] == N_FRAMES - 1
    assert counts["segment"] == 1 and counts["encode_images"] == 1
    assert reports["fuse"]["frames_rendered"] == 1  # its masks changed, so its associations did


def _drop_first_frame(source: Path, scene: Path) -> Path:
    shutil.copytree(source, scene)
    doc = json.loads((scene / "transforms.json").read_text())
    doc["frames"] = doc["frames"][1:]  # the first frame removed: every other frame's index shifts
    (scene / "transforms.json").write_text(json.dumps(doc))
    return scene


def test_a_dropped_frame_recomputes_no_perception(primed: dict, profile: dict, tmp_path: Path) -> None:
    """Perception is keyed on the images alone. Visibility is re-rendered: the lengths it uses
    are fractions of the scene scale, which is measured over all frames and moved with one gone."""
    scene = _drop_first_frame(primed["scene"], tmp_path / "scene")
    reports, counts = _run(scene, tmp_path / "out", primed["cache"], profile)
    assert reports["perceive"]["frames"] == N_FRAMES - 1
    assert reports["perceive"]["frames_computed"] == 0 and counts["encode_images"] == 0
    assert reports["fuse"]["scene_scale"]["value"] != primed["scale"]
    assert reports["fuse"]["frames_rendered"] == N_FRAMES - 1


def test_a_dropped_frame_with_the_scale_pinned_recomputes_nothing(
    primed: dict, profile: dict, tmp_path: Path
) -> None:
    """With `scene_scale` set, no length depends on which frames there are: nothing is redone."""
    pinned = PipelineParams(scene_scale=primed["scale"])
    _run(primed["scene"], tmp_path / "first", primed["cache"], profile, params=pinned)
    scene = _drop_first_frame(primed["scene"], tmp_path / "scene")
    reports, counts = _run(scene, tmp_path / "out", primed["cache"], profile, params=pinned)
    assert reports["perceive"]["frames_computed"] == 0 and counts["encode_images"] == 0
    assert reports["fuse"]["frames_rendered"] == 0


def test_another_profile_or_moved_splat_recomputes(primed: dict, profile: dict, tmp_path: Path) -> None:
    other = dict(
        profile, segmenter={"kind": "classical", "params": {**profile["segmenter"]["params"], "min_size": 30}}
    )
    reports, counts = _run(primed["scene"], tmp_path / "out", primed["cache"], other)
    assert reports["perceive"]["frames_computed"] == N_FRAMES
    assert counts["segment"] == N_FRAMES

    # Same images and models, Gaussians shifted: perception is reused, visibility is not.
    from bayesian_fields_core.scene.ply import read_ply, write_ply

    scene = tmp_path / "scene"
    shutil.copytree(primed["scene"], scene)
    g = read_ply(scene / "point_cloud.ply")
    g.means[:, 2] += 0.01
    write_ply(scene / "point_cloud.ply", g)
    reports, counts = _run(scene, tmp_path / "out2", primed["cache"], profile)
    assert reports["perceive"]["frames_computed"] == 0 and counts["encode_images"] == 0
    assert reports["fuse"]["frames_rendered"] == N_FRAMES


def test_bfields_run_reports_zero_frames_computed_after_editing_the_scene(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = tmp_path / "scene"
    shutil.copytree(scene_dir, scene)
    cache = tmp_path / "cache"

    def run(*extra: str) -> str:
        args = ["run", str(scene), "--cache-dir", str(cache), "--profile", str(profile_yaml), "-q", *extra]
        assert main(args) == 0
        return capsys.readouterr().out

    assert f"perception: {N_FRAMES} frames computed" in run("--out", str(tmp_path / "out"), "--task", "cup")
    (scene / "tasks.yaml").write_text("- red chair\n- blue cup\n")
    text = run("--out", str(scene / "out"))
    assert f"perception: 0 frames computed, {N_FRAMES} from cache" in text
    moved = tmp_path / "moved"
    shutil.move(scene, moved)
    scene = moved
    assert f"perception: 0 frames computed, {N_FRAMES} from cache" in run("--out", str(scene / "out"))
