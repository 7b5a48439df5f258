"""`check_run_inputs`: every problem of a run's inputs in one exception (issue 45), each with its
file and fix; one problem raised as itself, so its message and type are what they always were."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from PIL import Image

from bayesian_fields_core.checks.inputs import check_run_inputs
from bayesian_fields_core.errors import InputError, InputErrors

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"


def test_an_empty_folder_lacks_a_splat_and_cameras_at_once(tmp_path: Path) -> None:
    found = [InputError("no tasks given")]
    with pytest.raises(InputErrors) as refused:
        check_run_inputs(tmp_path, found=found)
    messages = [str(e) for e in refused.value.errors]
    assert messages[0] == "no tasks given"
    assert "no splat found" in messages[1] and "no cameras found" in messages[2], messages
    assert isinstance(refused.value, InputError)  # the service's 4xx mapping holds for it


def test_one_problem_is_raised_as_itself(tmp_path: Path) -> None:
    scene = tmp_path / "scene"
    shutil.copytree(SAMPLE, scene, ignore=shutil.ignore_patterns("sparse"))
    check_run_inputs(scene)  # the sample as it is: nothing to say
    with Image.open(scene / "images" / "frame_00000.png") as img:
        img.resize((10, 10)).save(scene / "images" / "frame_00000.png")
    with pytest.raises(InputError) as refused:
        check_run_inputs(scene)
    assert type(refused.value) is InputError
    assert str(refused.value).startswith(
        f"{scene / 'images' / 'frame_00000.png'}: image is 10x10 but its camera"
    )
