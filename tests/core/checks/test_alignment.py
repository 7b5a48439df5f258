"""The alignment check on the bundled sample and on misaligned copies of it (real splat, real
renderer, real photos): the sample passes, each misalignment is refused with its one-line cause."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.checks.alignment import assess_alignment, check_alignment, geometric_alignment
from bayesian_fields_core.checks.alignment_render import reduced_camera, weighted_zncc
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.types import Scene
from tests.support.scene_transforms import copy_scene, flip_camera_convention, move_splat, shuffle_images

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"
PARAMS = PipelineParams()


@pytest.fixture(scope="module")
def variant(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str, Callable[[Path], Path]], Scene]:
    made: dict[str, Scene] = {}

    def make(name: str, change: Callable[[Path], Path]) -> Scene:
        if name not in made:
            folder = copy_scene(SAMPLE, tmp_path_factory.mktemp("align") / name)
            made[name] = load_scene(change(folder))
        return made[name]

    return make


def _refusal(scene: Scene, **kwargs: object) -> str:
    with pytest.raises(InputError) as info:
        check_alignment(scene, PARAMS, **kwargs)  # type: ignore[arg-type]
    message = str(info.value)
    assert message.startswith("alignment: ") and "\n" not in message, message
    assert "alignment_check=false" in message
    return message


@pytest.mark.slow
def test_the_sample_passes_with_a_high_score() -> None:
    report = check_alignment(load_scene(SAMPLE), PARAMS)
    assert report is not None and report.passed and report.cause is None
    assert report.rendered is not None and report.rendered.score > 0.9
    assert len(report.rendered.frames) == PARAMS.alignment_frames
    assert report.geometry.frustum_share > 0.8 and report.geometry.flipped_frustum_share < 0.3
    assert 0.5 < report.geometry.extent_ratio < 2  # type: ignore[operator]
    assert "score 0.9" in report.summary() or "score 1.0" in report.summary()


@pytest.mark.slow
def test_scaled_and_shifted_splat_passes_geometry_but_is_refused_by_the_renders(variant) -> None:
    scene = variant("scaled-shifted", lambda f: move_splat(f, scale=0.5, shift=(0.4, 0.0, 0.0)))
    assert check_alignment(scene, PARAMS, rendered=False) is not None  # still in front of the cameras
    message = _refusal(scene)
    assert "renders of the splat do not match the photos" in message
    assert "dataparser_transforms.json" in message and "normalize_world_space" in message
    report = assess_alignment(scene, PARAMS)
    assert report.rendered is not None and report.rendered.score < 0.1


def test_opengl_flipped_cameras_are_refused_without_rendering(variant) -> None:
    scene = variant("flipped", flip_camera_convention)
    message = _refusal(scene, rendered=False)
    assert "OpenGL" in message and "OpenCV" in message
    geo = geometric_alignment(scene)
    assert geo.frustum_share < 0.2 and geo.flipped_frustum_share > 0.8


@pytest.mark.slow
def test_photos_of_other_cameras_are_refused(variant) -> None:
    message = _refusal(variant("shuffled", shuffle_images))
    assert "images folder" in message or "image order" in message


def test_a_dropped_scale_is_refused_by_the_extent_ratio(variant) -> None:
    scene = variant("tiny", lambda f: move_splat(f, scale=1e-3))
    message = _refusal(scene, rendered=False)
    assert "camera baseline" in message and "alignment_max_extent_ratio" in message


@pytest.mark.slow
def test_the_switch_and_the_thresholds_come_from_the_parameters(variant) -> None:
    scene = variant("scaled-shifted", lambda f: move_splat(f, scale=0.5, shift=(0.4, 0.0, 0.0)))
    assert check_alignment(scene, PipelineParams(alignment_check=False)) is None
    lenient = PipelineParams(alignment_min_score=-1.0)
    report = check_alignment(scene, lenient)
    assert report is not None and report.passed


def test_reduced_camera_scales_intrinsics_with_the_image() -> None:
    frame = load_scene(SAMPLE).frames[0]  # 320 x 240
    K, width, height = reduced_camera(frame, 160)
    assert (width, height) == (160, 120)
    np.testing.assert_allclose(K[:2], frame.K[:2] / 2)
    assert reduced_camera(frame, 1000)[1:] == (320, 240)


def test_weighted_zncc_ignores_gain_and_offset_and_unweighted_pixels() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(20, 30))
    weights = np.zeros((20, 30))
    weights[:, :15] = 1.0
    b = 3.0 * a + 2.0
    b[:, 15:] = rng.normal(size=(20, 15))  # unweighted pixels do not count
    assert weighted_zncc(a, b, weights) == pytest.approx(1.0)
    assert weighted_zncc(a, -a, weights) == pytest.approx(-1.0)
    assert weighted_zncc(a, b, np.zeros_like(a)) == 0.0  # nothing rendered: no evidence
    assert weighted_zncc(a, np.ones_like(a), weights) == 0.0  # a flat photo
