"""Every path a camera file names stays inside the scene folder (issue 12, item 2).

For each reader (transforms.json file_path / depth_file_path / mask_path, COLMAP text and binary
image names, cameras.json img_name) an absolute name, a `..` name and a symlink out of the folder
are refused, and the refusal is the same whether the outside target exists or not: the message
is compared byte for byte between an existing outside file and a missing one (no oracle).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from PIL import Image

from bayesian_fields_core.checks.upload import validate_scene_folder
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.colmap import read_colmap, write_colmap_binary, write_colmap_text
from bayesian_fields_core.scene.files import resolve_inside
from bayesian_fields_core.scene.inria import read_cameras_json, write_cameras_json
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.nerfstudio import read_transforms, write_transforms
from bayesian_fields_core.scene.ply import write_ply

from .conftest import random_gaussians


@pytest.fixture
def outside(tmp_path: Path) -> tuple[Path, Path]:
    """(an existing image outside the scene, a path beside it that does not exist)."""
    folder = tmp_path / "host"
    folder.mkdir()
    Image.new("RGB", (640, 480)).save(folder / "secret.png")
    return folder / "secret.png", folder / "missing.png"


def _scene(tmp_path: Path) -> Path:
    scene = tmp_path / "scene"
    (scene / "images").mkdir(parents=True)
    write_ply(scene / "splat.ply", random_gaussians(50, 0, extra=False))
    return scene


def _refusal(fn, *args) -> str:
    with pytest.raises(InputError) as info:
        fn(*args)
    return str(info.value)


def _names(outside: tuple[Path, Path], scene_images: Path) -> dict[str, tuple[str, str]]:
    """Escape kinds -> (name of the existing outside file, name of the missing one)."""
    existing, missing = outside
    return {
        "absolute": (str(existing), str(missing)),
        "dotdot": (os.path.relpath(existing, scene_images), os.path.relpath(missing, scene_images)),
    }


def _same_refusal(message_existing: str, message_missing: str, existing: Path, missing: Path) -> None:
    """Identical messages once the two names themselves are blanked out."""
    a = message_existing.replace(existing.name, "NAME")
    b = message_missing.replace(missing.name, "NAME")
    assert a == b, (a, b)
    assert "does not exist" not in a and "not found" not in a


def test_resolve_inside_refuses_every_escape(tmp_path: Path, outside) -> None:
    root = tmp_path / "root"
    (root / "sub").mkdir(parents=True)
    (root / "link").symlink_to(outside[0])
    (root / "dangling").symlink_to(outside[1])
    assert resolve_inside(root, "sub/../a.png", what="image", source="s") == (root / "a.png").resolve()
    for name in (str(outside[0]), "../host/secret.png", "sub/../../host/secret.png", "link", "dangling", ""):
        with pytest.raises(InputError):
            resolve_inside(root, name, what="image", source="s")
    with pytest.raises(InputError) as a:
        resolve_inside(root, "link", what="image", source="s")
    with pytest.raises(InputError) as b:
        resolve_inside(root, "dangling", what="image", source="s")
    assert str(a.value).replace("link", "X") == str(b.value).replace("dangling", "X")


@pytest.mark.parametrize("kind", ["absolute", "dotdot"])
@pytest.mark.parametrize("key", ["file_path", "depth_file_path", "mask_path"])
def test_transforms_paths_stay_inside(tmp_path: Path, frames, outside, kind: str, key: str) -> None:
    scene = _scene(tmp_path)
    for f in frames:
        Image.new("RGB", (f.width, f.height)).save(scene / "images" / f.name)
        f.image_path = scene / "images" / f.name
    write_transforms(scene / "transforms.json", frames)
    doc = json.loads((scene / "transforms.json").read_text())
    messages = []
    for name in _names(outside, scene)[kind]:
        doc["frames"][1][key] = name
        (scene / "transforms.json").write_text(json.dumps(doc))
        messages.append(_refusal(read_transforms, scene / "transforms.json"))
        messages.append(_refusal(validate_scene_folder, scene))
    assert "frames[1]" in messages[0] and ("image" if key == "file_path" else key) in messages[0]
    assert ("absolute" if kind == "absolute" else "leaves the scene folder") in messages[0]
    _same_refusal(messages[0], messages[2], *outside)
    _same_refusal(messages[1], messages[3], *outside)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("kind", ["absolute", "dotdot"])
def test_colmap_image_names_stay_inside(tmp_path: Path, frames, outside, kind: str, binary: bool) -> None:
    scene = _scene(tmp_path)
    messages = []
    for name in _names(outside, scene / "images")[kind]:
        frames[0].name = name
        (write_colmap_binary if binary else write_colmap_text)(scene / "sparse" / "0", frames)
        messages.append(_refusal(read_colmap, scene / "sparse" / "0", scene / "images"))
        messages.append(_refusal(load_scene, scene))
    assert "image path" in messages[0]
    _same_refusal(messages[0], messages[2], *outside)
    _same_refusal(messages[1], messages[3], *outside)


@pytest.mark.parametrize("kind", ["absolute", "dotdot"])
def test_cameras_json_img_names_stay_inside(tmp_path: Path, frames, outside, kind: str) -> None:
    scene = _scene(tmp_path)
    write_cameras_json(scene / "cameras.json", frames[:1])  # frames[0] has a centred principal point
    doc = json.loads((scene / "cameras.json").read_text())
    messages = []
    # img_name has no extension in INRIA files: the reader tries .png etc., each checked first.
    for name in _names(outside, scene / "images")[kind]:
        doc[0]["img_name"] = name.removesuffix(".png")
        (scene / "cameras.json").write_text(json.dumps(doc))
        messages.append(_refusal(read_cameras_json, scene / "cameras.json"))
        messages.append(_refusal(validate_scene_folder, scene))
    assert "[0]" in messages[0]
    _same_refusal(messages[0].replace("secret", "missing"), messages[2], *outside)
    _same_refusal(messages[1].replace("secret", "missing"), messages[3], *outside)


def test_symlink_inside_the_folder_pointing_out_is_refused(tmp_path: Path, frames, outside) -> None:
    """A CLI user's scene folder with a symlinked image leaving it: refused like a `..` name."""
    scene = _scene(tmp_path)
    for f in frames:
        Image.new("RGB", (f.width, f.height)).save(scene / "images" / f.name)
    (scene / "images" / frames[0].name).unlink()
    (scene / "images" / frames[0].name).symlink_to(outside[0])
    write_colmap_text(scene / "sparse" / "0", frames)
    message = _refusal(load_scene, scene)
    assert frames[0].name in message and "leaves the scene folder" in message


def test_paths_inside_still_load(tmp_path: Path, frames) -> None:
    """`a/../b` that stays inside, and extension-less INRIA names, still resolve."""
    scene = _scene(tmp_path)
    for f in frames:
        Image.new("RGB", (f.width, f.height)).save(scene / "images" / f.name)
        f.image_path = scene / "images" / f.name
    write_transforms(scene / "transforms.json", frames)
    doc = json.loads((scene / "transforms.json").read_text())
    doc["frames"][0]["file_path"] = "images/../images/" + frames[0].name
    (scene / "transforms.json").write_text(json.dumps(doc))
    assert validate_scene_folder(scene)["frames"] == 3
