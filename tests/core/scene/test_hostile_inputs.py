"""Hostile or degenerate inputs give an InputError naming the problem, never another exception
(issue 12, items 3 and 8): empty splats, counts that disagree with the body, degenerate values,
camera JSON nested past the recursion limit, numbers past Python's limits, and the frame limit
applied before a single image is decoded."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.checks.upload import validate_scene_folder
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.task_list import load_tasks
from bayesian_fields_core.scene.colmap import read_colmap, write_colmap_binary
from bayesian_fields_core.scene.inria import read_cameras_json
from bayesian_fields_core.scene.nerfstudio import read_transforms, write_transforms
from bayesian_fields_core.scene.ply import read_ply, write_ply
from bayesian_fields_core.scene.sanity import LOG_SCALE_RANGE, MAX_ABS_POSITION

from .conftest import random_gaussians


def _message(fn, *args, **kwargs) -> str:
    with pytest.raises(InputError) as info:
        fn(*args, **kwargs)
    return str(info.value)


@pytest.mark.parametrize("ascii", [False, True])
def test_zero_gaussians_is_refused(tmp_path: Path, ascii: bool) -> None:
    path = tmp_path / "empty.ply"
    write_ply(path, random_gaussians(0, 0, extra=False), ascii=ascii)
    assert "no Gaussians" in _message(read_ply, path)


@pytest.mark.parametrize("ascii", [False, True])
def test_body_longer_than_the_header_count_is_refused(tmp_path: Path, ascii: bool) -> None:
    path = tmp_path / "long.ply"
    write_ply(path, random_gaussians(10, 0, extra=False), ascii=ascii)
    path.write_bytes(path.read_bytes().replace(b"element vertex 10", b"element vertex 7", 1))
    assert "the vertex count does not match the data" in _message(read_ply, path)


def test_a_few_stray_trailing_bytes_are_tolerated(tmp_path: Path) -> None:
    path = tmp_path / "newline.ply"
    write_ply(path, random_gaussians(10, 0, extra=False))
    path.write_bytes(path.read_bytes() + b"\n")
    assert len(read_ply(path)) == 10


def test_body_shorter_than_the_header_count_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "short.ply"
    write_ply(path, random_gaussians(10, 0, extra=False))
    path.write_bytes(path.read_bytes().replace(b"element vertex 10", b"element vertex 12", 1))
    assert "truncated vertex data" in _message(read_ply, path)


@pytest.mark.parametrize(
    ("field", "value", "fragment"),
    [
        ("quats", 0.0, "zero-length rotation quaternion"),
        ("log_scales", LOG_SCALE_RANGE[1] + 1, "log-scale"),
        ("log_scales", LOG_SCALE_RANGE[0] - 1, "log-scale"),
        ("means", MAX_ABS_POSITION * 10, "beyond"),
    ],
)
def test_degenerate_but_finite_splats_are_refused(
    tmp_path: Path, field: str, value: float, fragment: str
) -> None:
    g = random_gaussians(20, 0, extra=False)
    getattr(g, field)[[2, 5]] = value
    path = tmp_path / "degenerate.ply"
    write_ply(path, g)
    message = _message(read_ply, path)
    assert "degenerate splat" in message and fragment in message and "2 Gaussians" in message


def test_suspicious_splats_pass_with_warnings(tmp_path: Path, frames) -> None:
    g = random_gaussians(50, 0, extra=False)
    g.log_scales[:] = -3.0
    g.opacity_logits[:] = -20.0  # invisible
    _write_scene(tmp_path, frames, g)
    summary = validate_scene_folder(tmp_path)
    assert any("nothing will render" in w for w in summary["warnings"])
    g.opacity_logits[:] = 0.0
    _write_scene(tmp_path, frames, g)
    assert validate_scene_folder(tmp_path)["warnings"] == []


def _write_scene(folder: Path, frames, g=None) -> None:
    (folder / "images").mkdir(parents=True, exist_ok=True)
    write_ply(folder / "splat.ply", g if g is not None else random_gaussians(30, 0, extra=False))
    for f in frames:
        Image.new("RGB", (f.width, f.height)).save(folder / "images" / f.name)
        f.image_path = folder / "images" / f.name
    write_transforms(folder / "transforms.json", frames)


def test_frame_limit_is_checked_before_any_image_is_decoded(tmp_path: Path, frames) -> None:
    _write_scene(tmp_path, frames)
    (tmp_path / "images" / frames[0].name).write_bytes(b"not an image at all")
    message = _message(validate_scene_folder, tmp_path, max_frames=2)
    assert "3 frames; at most 2 are allowed" in message
    assert "cannot decode" in _message(validate_scene_folder, tmp_path, max_frames=3)


def _deep(depth: int) -> str:
    return "[" * depth + "]" * depth


@pytest.mark.parametrize(
    ("name", "reader"),
    [("transforms.json", read_transforms), ("cameras.json", read_cameras_json)],
)
@pytest.mark.parametrize(
    "text",
    [
        _deep(100_000),
        '{"frames": ' + _deep(50_000) + "}",
        '{"w": 1' + "0" * 5000 + "}",  # past Python's int-digits limit (ValueError, not JSON's)
        "\udcff".encode("utf-8", "surrogateescape").decode("latin-1"),
    ],
)
def test_camera_json_that_cannot_be_parsed(tmp_path: Path, name: str, reader, text: str) -> None:
    path = tmp_path / name
    path.write_text(text, encoding="latin-1")
    assert name in _message(reader, path)


def test_camera_json_with_unusable_numbers(tmp_path: Path, frames) -> None:
    _write_scene(tmp_path, frames)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    for f in doc["frames"]:
        del f["fl_x"], f["fl_y"]
    doc["camera_angle_x"] = 0.0
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    assert "camera_angle_x" in _message(read_transforms, tmp_path / "transforms.json")
    cams = [{"img_name": "a", "width": 1e400, "height": 2, "position": [0, 0, 0],
             "rotation": np.eye(3).tolist(), "fx": 1, "fy": 1}]  # fmt: skip
    (tmp_path / "cameras.json").write_text(json.dumps(cams).replace("Infinity", "1e400"))
    assert "cameras.json" in _message(read_cameras_json, tmp_path / "cameras.json")


def test_colmap_binary_with_garbage_is_an_input_error(tmp_path: Path, frames) -> None:
    sparse = tmp_path / "sparse" / "0"
    write_colmap_binary(sparse, frames)
    blob = (sparse / "images.bin").read_bytes()
    (sparse / "images.bin").write_bytes(blob[:8] + b"\xff" * 80 + blob[88:])  # bad name bytes / ids
    with pytest.raises(InputError):
        read_colmap(sparse, tmp_path / "images")
    (sparse / "cameras.bin").write_bytes(struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, 1, 0, 0) + bytes(32))
    write_colmap_binary(tmp_path / "ok", frames[:1])
    (sparse / "images.bin").write_bytes((tmp_path / "ok" / "images.bin").read_bytes())
    assert "invalid size" in _message(read_colmap, sparse, tmp_path / "images")


def test_task_file_nested_too_deeply(tmp_path: Path) -> None:
    for suffix, text in ((".yaml", "- " * 5000 + "a"), (".json", _deep(100_000))):
        path = tmp_path / f"tasks{suffix}"
        path.write_text(text)
        assert "tasks" in _message(load_tasks, path)
