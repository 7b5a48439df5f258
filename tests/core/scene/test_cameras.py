"""Camera formats: every reader/writer agrees on where a known 3D point lands, plus conventions
checked against hand-written files, ordering, distortion models and clear errors."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from PIL import Image

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.transforms import quat_to_rotmat, rotmat_to_quat
from bayesian_fields_core.scene.colmap import read_colmap, write_colmap_binary, write_colmap_text
from bayesian_fields_core.scene.inria import read_cameras_json, write_cameras_json
from bayesian_fields_core.scene.nerfstudio import read_transforms, write_transforms

from .conftest import expected_pixel, project


def by_name(frames):
    return {f.name: f for f in frames}


def check_projections(original, loaded):
    """Loaded cameras put known points on the first-principles pixel, like the originals."""
    loaded = by_name(loaded)
    for frame in original:
        other = loaded[frame.name]
        assert (other.width, other.height) == (frame.width, frame.height)
        for offsets in [(0.0, 0.0), (0.2, -0.1), (-0.3, 0.25)]:
            point, pixel = expected_pixel(frame, *offsets)
            np.testing.assert_allclose(project(frame, point), pixel, atol=1e-9)
            np.testing.assert_allclose(project(other, point), pixel, atol=1e-6)


def test_quaternion_round_trip():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.sign(q[:, :1])
    np.testing.assert_allclose(rotmat_to_quat(quat_to_rotmat(q)), q, atol=1e-12)
    # 90 degrees about z maps x to y
    np.testing.assert_allclose(
        quat_to_rotmat(np.array([np.sqrt(0.5), 0, 0, np.sqrt(0.5)])) @ [1, 0, 0], [0, 1, 0], atol=1e-12
    )


@pytest.mark.parametrize("writer", [write_colmap_text, write_colmap_binary])
def test_colmap_round_trip(tmp_path, frames, writer):
    writer(tmp_path / "sparse" / "0", frames)
    loaded = read_colmap(tmp_path / "sparse" / "0")
    check_projections(frames, loaded)
    # sorted by name, numbers compared numerically
    assert [f.name for f in loaded] == ["frame_1.png", "frame_2.png", "frame_10.png"]
    assert loaded[0].image_path == tmp_path / "sparse" / "images" / "frame_1.png"
    assert all(f.distortion is None for f in loaded)


def test_colmap_explicit_order_and_images_dir(tmp_path, frames):
    write_colmap_text(tmp_path, frames)
    loaded = read_colmap(tmp_path, tmp_path / "imgs", order=["frame_10.png", "frame_2.png"])
    assert [f.name for f in loaded] == ["frame_10.png", "frame_2.png"]
    assert loaded[0].image_path == tmp_path / "imgs" / "frame_10.png"
    with pytest.raises(InputError, match="not in the COLMAP model: nope.png"):
        read_colmap(tmp_path, order=["nope.png"])


def test_transforms_round_trip(tmp_path, frames):
    write_transforms(tmp_path / "transforms.json", frames)
    check_projections(frames, read_transforms(tmp_path / "transforms.json"))


def test_cameras_json_round_trip(tmp_path, frames):
    centred = [f for f in frames if np.allclose(f.K[:2, 2], [f.width / 2, f.height / 2])]
    assert len(centred) == 2
    write_cameras_json(tmp_path / "cameras.json", centred)
    loaded = read_cameras_json(tmp_path / "cameras.json")
    assert [f.name for f in loaded] == ["frame_2", "frame_1"]  # INRIA names carry no extension
    for f in centred:
        f.name = f.name.removesuffix(".png")
    check_projections(centred, loaded)
    with pytest.raises(InputError, match="off-centre principal point"):
        write_cameras_json(tmp_path / "bad.json", frames)


# Hand-written files pin the conventions independently of our writers: a camera 5 units from the
# origin looking at it, fx = fy = 100, principal point (50, 40). A world point 1 unit to the
# camera's right must land at u = 50 + 100/5 = 70; one unit "camera-down" at v = 40 + 20 = 60.


def test_colmap_text_convention(tmp_path):
    (tmp_path / "cameras.txt").write_text("# c\n1 PINHOLE 100 80 100 100 50 40\n")
    # identity rotation, t = (0, 0, 5): camera centre at (0, 0, -5) looking along +z
    (tmp_path / "images.txt").write_text("# i\n7 1 0 0 0 0 0 5 1 a.jpg\n\n")
    (frame,) = read_colmap(tmp_path)
    np.testing.assert_allclose(project(frame, np.array([1.0, 0, 0])), [70, 40])
    np.testing.assert_allclose(project(frame, np.array([0, 1.0, 0])), [50, 60])
    np.testing.assert_allclose(frame.camera_centre, [0, 0, -5])


def test_transforms_opengl_convention(tmp_path):
    # OpenGL camera-to-world: identity rotation at (0, 0, 5) looks down -z at the origin, y up.
    doc = {
        "fl_x": 100, "fl_y": 100, "cx": 50, "cy": 40, "w": 100, "h": 80,
        "frames": [{"file_path": "a.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5], [0, 0, 0, 1]]}],
    }  # fmt: skip
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    (frame,) = read_transforms(tmp_path / "transforms.json")
    np.testing.assert_allclose(project(frame, np.array([1.0, 0, 0])), [70, 40])
    np.testing.assert_allclose(project(frame, np.array([0, 1.0, 0])), [50, 20])  # world up = image up
    assert frame.depth_path is None and frame.image_path == tmp_path / "a.png"


def test_cameras_json_convention(tmp_path):
    doc = [{"id": 0, "img_name": "a", "width": 100, "height": 80, "position": [0, 0, -5],
            "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "fx": 100, "fy": 100}]  # fmt: skip
    (tmp_path / "cameras.json").write_text(json.dumps(doc))
    (frame,) = read_cameras_json(tmp_path / "cameras.json")
    np.testing.assert_allclose(project(frame, np.array([1.0, 0, 0])), [70, 40])
    np.testing.assert_allclose(project(frame, np.array([0, 1.0, 0])), [50, 60])
    # a rotated camera: C2W rotation columns are the camera axes in the world
    # columns: camera x = world z, camera y = world x, camera z (forward) = world y
    rot = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=float)
    doc[0].update(position=[0, -5, 0], rotation=rot.tolist())
    (tmp_path / "cameras.json").write_text(json.dumps(doc))
    (frame,) = read_cameras_json(tmp_path / "cameras.json")
    np.testing.assert_allclose(project(frame, np.array([0, 0, 0])), [50, 40])
    np.testing.assert_allclose(project(frame, np.array([0, 0, 1.0])), [70, 40])  # camera x = world z


def test_blender_camera_angle_and_image_size(tmp_path):
    (tmp_path / "train").mkdir()
    Image.new("RGBA", (200, 100)).save(tmp_path / "train" / "r_0.png")
    angle = 2 * np.arctan(0.5)  # fx = 0.5 * w / tan(angle / 2) = 200
    doc = {
        "camera_angle_x": angle,
        "frames": [{"file_path": "./train/r_0", "transform_matrix": np.eye(4).tolist()}],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    (frame,) = read_transforms(tmp_path / "transforms.json")
    assert (frame.width, frame.height) == (200, 100)
    np.testing.assert_allclose(frame.K, [[200, 0, 100], [0, 200, 50], [0, 0, 1]])
    assert frame.image_path.name == "r_0.png"


def test_per_frame_intrinsics_and_distortion_override_shared(tmp_path):
    pose = np.eye(4).tolist()
    doc = {
        "fl_x": 100, "fl_y": 100, "cx": 50, "cy": 40, "w": 100, "h": 80, "k1": 0.0,
        "frames": [
            {"file_path": "a.png", "transform_matrix": pose},
            {"file_path": "b.png", "transform_matrix": pose, "fl_x": 80, "w": 90, "k1": -0.1, "p2": 0.01},
        ],
    }  # fmt: skip
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    a, b = read_transforms(tmp_path / "transforms.json")
    assert a.distortion is None and a.K[0, 0] == 100 and a.width == 100
    assert b.K[0, 0] == 80 and b.K[1, 1] == 100 and b.width == 90
    assert b.distortion == {"k1": -0.1, "p2": 0.01}


def test_colmap_distorted_models(tmp_path):
    (tmp_path / "cameras.txt").write_text(
        "1 SIMPLE_RADIAL 100 80 90 50 40 0\n"
        "2 RADIAL 100 80 90 50 40 -0.1 0.02\n"
        "3 OPENCV 100 80 90 95 50 40 -0.1 0.02 0.001 0\n"
        "4 SIMPLE_PINHOLE 100 80 90 50 40\n"
    )
    (tmp_path / "images.txt").write_text("".join(f"{i} 1 0 0 0 0 0 5 {i} im{i}.png\n\n" for i in range(1, 5)))
    frames = read_colmap(tmp_path)
    assert [f.distortion for f in frames] == [
        None,
        {"k1": -0.1, "k2": 0.02},
        {"k1": -0.1, "k2": 0.02, "p1": 0.001, "p2": 0.0},
        None,
    ]
    assert frames[2].K[1, 1] == 95 and frames[0].K[0, 0] == frames[0].K[1, 1] == 90
    # the writers keep the distortion (and pick the same models) through a round trip
    write_colmap_binary(tmp_path / "bin", frames)
    assert [f.distortion for f in read_colmap(tmp_path / "bin")] == [f.distortion for f in frames]
    write_colmap_text(tmp_path / "txt", frames)
    assert (tmp_path / "txt" / "cameras.txt").read_text().split("\n")[3].split()[1] == "RADIAL"


# ---- errors name the file and the problem ------------------------------------------------------


def test_bad_colmap_line(tmp_path):
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 100 80 100 100 50 40\n")
    (tmp_path / "images.txt").write_text("# header\n1 1 0 0 zero 0 0 5 1 a.jpg\n\n")
    with pytest.raises(InputError, match=r"images\.txt:2: bad image line"):
        read_colmap(tmp_path)
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 100 80 100 100\n")
    with pytest.raises(
        InputError, match=r"cameras\.txt:1: camera 1: model PINHOLE takes 4 parameters, got 2"
    ):
        read_colmap(tmp_path)


def test_unsupported_colmap_model(tmp_path):
    (tmp_path / "cameras.txt").write_text("3 OPENCV_FISHEYE 100 80 100 100 50 40 0.1 0 0 0\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 5 3 a.jpg\n\n")
    with pytest.raises(
        InputError, match=r"cameras\.txt: camera 3 uses the unsupported camera model OPENCV_FISHEYE"
    ):
        read_colmap(tmp_path)


def test_colmap_image_with_unknown_camera(tmp_path):
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 100 80 100 100 50 40\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 5 9 a.jpg\n\n")
    with pytest.raises(InputError, match="image a.jpg refers to camera 9"):
        read_colmap(tmp_path)


def test_truncated_colmap_binary(tmp_path, frames):
    write_colmap_binary(tmp_path, frames)
    blob = (tmp_path / "images.bin").read_bytes()
    (tmp_path / "images.bin").write_bytes(blob[:-20])
    with pytest.raises(InputError, match=r"images\.bin: truncated while reading"):
        read_colmap(tmp_path)
    (tmp_path / "cameras.bin").write_bytes(struct.pack("<QiiQQ", 1, 1, 42, 10, 10))
    write_colmap_binary(tmp_path / "ok", frames)
    (tmp_path / "images.bin").write_bytes((tmp_path / "ok" / "images.bin").read_bytes())
    with pytest.raises(InputError, match="camera 1: unknown camera model id 42"):
        read_colmap(tmp_path)


def test_missing_colmap_model(tmp_path):
    with pytest.raises(InputError, match="no COLMAP model"):
        read_colmap(tmp_path)


@pytest.mark.parametrize(
    ("doc", "problem"),
    [
        ({"fl_x": 100, "w": 10, "h": 10}, "no 'frames' list"),
        ({"fl_x": 100, "w": 10, "h": 10, "frames": []}, "no 'frames' list"),
        ({"w": 10, "h": 10, "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]},
         r"frames\[0\]: no intrinsics"),
        ({"fl_x": 100, "w": 10, "h": 10, "frames": [{"file_path": "a.png"}]}, r"frames\[0\]: frame has no transform_matrix"),
        ({"fl_x": 100, "w": 10, "h": 10, "frames": [{"file_path": "a.png", "transform_matrix": (2 * np.eye(4)).tolist()}]},
         "not a rigid transform"),
        ({"fl_x": "big", "w": 10, "h": 10, "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]},
         "fl_x must be a finite number"),
        ({"fl_x": 100, "w": 10, "h": 10, "camera_model": "OPENCV_FISHEYE",
          "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}, "unsupported camera_model"),
    ],
)  # fmt: skip
def test_bad_transforms(tmp_path, doc, problem):
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=problem) as info:
        read_transforms(path)
    assert str(path) in str(info.value)


def test_transforms_not_json(tmp_path):
    path = tmp_path / "transforms.json"
    path.write_text("{frames: ")
    with pytest.raises(InputError, match="not valid JSON"):
        read_transforms(path)


def test_cameras_json_missing_fields(tmp_path):
    path = tmp_path / "cameras.json"
    path.write_text(
        json.dumps([{"id": 0, "img_name": "a", "width": 10, "height": 10, "position": [0, 0, 0]}])
    )
    with pytest.raises(InputError, match=r"cameras\.json \[0\]: camera entry lacks rotation, fx, fy"):
        read_cameras_json(path)
    path.write_text(json.dumps({"not": "a list"}))
    with pytest.raises(InputError, match="non-empty JSON list"):
        read_cameras_json(path)
