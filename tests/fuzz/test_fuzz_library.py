"""Fuzz the library's validators: the property is "a result, or an InputError; never another
exception; nothing changed on disk; every path a result names lies inside the scene folder".

Budgets (full CI run, `BFIELDS_FUZZ_SCALE=1`) are the numbers passed to `budget`.
"""

from __future__ import annotations

import hashlib
import io
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from bayesian_fields_core.checks.upload import validate_scene_folder
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.task_list import MAX_TASK_CHARS, MAX_TASKS, load_tasks, normalise_tasks
from bayesian_fields_core.scene.colmap import read_colmap
from bayesian_fields_core.scene.inria import read_cameras_json
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.nerfstudio import read_transforms
from bayesian_fields_core.scene.ply import read_ply, write_ply
from bayesian_fields_core.scene.types import Gaussians
from bayesian_fields_service.scenes.archives import ArchiveLimits, extract_archive

from . import strategies as fz
from .conftest import budget, count

pytestmark = pytest.mark.fuzz

ARCHIVE_LIMITS = ArchiveLimits(max_members=20, max_bytes=4096)


def _snapshot(folder: Path) -> dict[str, str]:
    """Relative path -> sha256 (or 'dir' / 'link') of everything under `folder`."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_symlink():
            out[rel] = "link"
        elif p.is_dir():
            out[rel] = "dir"
        else:
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _png(colour: tuple[int, int, int]) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", fz.IMAGE_SIZE, colour).save(buf, format="PNG")
    return buf.getvalue()


IMAGE_BYTES = _png((9, 9, 9))
SECRET_BYTES = _png((0, 0, 0))


@contextmanager
def workspace(*, images: bool = True) -> Iterator[tuple[Path, Path]]:
    """(scene folder with two real images and a valid splat, a host folder beside it).

    On exit both must be exactly as they were when the caller finished writing its inputs,
    which the caller marks by calling the yielded folders' snapshot (see `checked`)."""
    with tempfile.TemporaryDirectory(prefix="bf-fuzz-") as tmp:
        root = Path(tmp)
        scene, host = root / "scene", root / "host"
        (scene / "images").mkdir(parents=True)
        host.mkdir()
        for name in fz.IMAGE_NAMES if images else ():
            (scene / "images" / name).write_bytes(IMAGE_BYTES)
        (host / "secret.png").write_bytes(SECRET_BYTES)  # a host file worth stealing
        yield scene, host


def checked(scene: Path, host: Path, fn: Callable[[], object]) -> object | None:
    """Run `fn`; InputError -> None; anything else propagates. Disk must be unchanged after."""
    before = (_snapshot(scene), _snapshot(host))
    try:
        result = fn()
    except InputError as exc:
        assert str(exc), "an InputError must carry a message"
        result = None
    assert (_snapshot(scene), _snapshot(host)) == before, "a validator changed files on disk"
    return result


def _inside(frames, folder: Path) -> None:
    base = folder.resolve()
    for f in frames:
        for p in (f.image_path, f.depth_path):
            assert p is None or Path(p).resolve().is_relative_to(base), (p, base)


def _tiny_splat_bytes() -> bytes:
    n = 4
    with tempfile.TemporaryDirectory() as tmp:
        write_ply(
            Path(tmp) / "s.ply",
            Gaussians(
                means=np.arange(3 * n, dtype=np.float32).reshape(n, 3),
                log_scales=np.full((n, 3), -2.0, np.float32),
                quats=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
                opacity_logits=np.zeros(n, np.float32),
                sh=np.zeros((n, 1, 3), np.float32),
            ),
        )
        return (Path(tmp) / "s.ply").read_bytes()


SPLAT_BYTES = _tiny_splat_bytes()


@budget(2500)
@given(blob=fz.ply_files())
def test_fuzz_ply(blob: bytes) -> None:
    count("library: PLY header + body -> read_ply")
    with workspace(images=False) as (scene, host):
        (scene / "splat.ply").write_bytes(blob)
        g = checked(scene, host, lambda: read_ply(scene / "splat.ply"))
        if g is not None:
            assert len(g) > 0 and np.isfinite(g.means).all() and np.isfinite(g.sh).all()


def _camera_case(scene: Path, host: Path, reader: Callable[[], list]) -> None:
    (scene / "splat.ply").write_bytes(SPLAT_BYTES)
    frames = checked(scene, host, reader)
    if frames is not None:
        _inside(frames, scene)
    summary = checked(scene, host, lambda: validate_scene_folder(scene, max_frames=2))
    if summary is not None:
        assert 1 <= summary["frames"] <= 2
        scene_loaded = checked(scene, host, lambda: load_scene(scene))
        assert scene_loaded is not None, "a folder that validates must load"
        _inside(scene_loaded.frames, scene)


@budget(1500)
@given(doc=fz.transforms_docs())
@pytest.mark.slow
def test_fuzz_transforms_json(doc: bytes) -> None:
    count("library: transforms.json -> read_transforms, validate_scene_folder")
    with workspace() as (scene, host):
        (scene / "transforms.json").write_bytes(doc)
        _camera_case(scene, host, lambda: read_transforms(scene / "transforms.json"))


@budget(1000)
@given(doc=fz.cameras_json_docs())
def test_fuzz_cameras_json(doc: bytes) -> None:
    count("library: cameras.json -> read_cameras_json, validate_scene_folder")
    with workspace() as (scene, host):
        (scene / "cameras.json").write_bytes(doc)
        _camera_case(scene, host, lambda: read_cameras_json(scene / "cameras.json"))


@budget(1000)
@given(model=fz.colmap_text_models())
def test_fuzz_colmap_text(model: tuple[bytes, bytes]) -> None:
    count("library: COLMAP text -> read_colmap, validate_scene_folder")
    with workspace() as (scene, host):
        sparse = scene / "sparse" / "0"
        sparse.mkdir(parents=True)
        (sparse / "cameras.txt").write_bytes(model[0])
        (sparse / "images.txt").write_bytes(model[1])
        _camera_case(scene, host, lambda: read_colmap(sparse, scene / "images"))


@budget(1000)
@given(model=fz.colmap_binary_models())
def test_fuzz_colmap_binary(model: tuple[bytes, bytes]) -> None:
    count("library: COLMAP binary -> read_colmap, validate_scene_folder")
    with workspace() as (scene, host):
        sparse = scene / "sparse" / "0"
        sparse.mkdir(parents=True)
        (sparse / "cameras.bin").write_bytes(model[0])
        (sparse / "images.bin").write_bytes(model[1])
        _camera_case(scene, host, lambda: read_colmap(sparse, scene / "images"))


def _archive_case(blob: bytes, name: str) -> None:
    with workspace() as (scene, host):
        archive = scene.parent / name
        archive.write_bytes(blob)
        dest = scene / "extracted"
        outside_before = (_snapshot(scene / "images"), _snapshot(host), archive.read_bytes())
        try:
            written = extract_archive(archive, dest, ARCHIVE_LIMITS, source=name)
        except InputError as exc:
            assert str(exc).startswith(name) and str(scene.parent) not in str(exc)
            written = None
        assert (_snapshot(scene / "images"), _snapshot(host), archive.read_bytes()) == outside_before
        assert sorted(p.name for p in scene.parent.iterdir()) == sorted(["scene", "host", name])
        for p in dest.rglob("*") if dest.exists() else ():
            assert not p.is_symlink() and p.resolve().is_relative_to(dest.resolve())
        if written is not None:
            assert all((dest / p).is_file() for p in written)
            assert sum((dest / p).stat().st_size for p in written) <= ARCHIVE_LIMITS.max_bytes


@budget(1000)
@given(blob=fz.zip_archives())
def test_fuzz_zip_extraction(blob: bytes) -> None:
    count("library: zip archives -> extract_archive")
    _archive_case(blob, "images.zip")


@budget(700)
@given(blob=fz.tar_archives())
def test_fuzz_tar_extraction(blob: bytes) -> None:
    count("library: tar(.gz/.bz2/.xz) archives -> extract_archive")
    _archive_case(blob, "images.tar")


@budget(2000)
@given(raw=fz.task_lists)
def test_fuzz_task_normalisation(raw: object) -> None:
    count("library: task lists -> normalise_tasks")
    try:
        tasks = normalise_tasks(raw)
    except InputError:
        return
    assert 1 <= len(tasks) <= MAX_TASKS and len(set(tasks)) == len(tasks)
    assert all(isinstance(t, str) and t.strip() and len(t) <= MAX_TASK_CHARS for t in tasks)


@budget(500)
@given(
    suffix=st.sampled_from([".yaml", ".json", ".txt"]),
    text=st.one_of(st.text(max_size=200), fz.task_lists.map(repr)),
    deep=st.sampled_from([0] * 19 + [1100]),
)
def test_fuzz_task_files(suffix: str, text: str, deep: int) -> None:
    count("library: task files (yaml/json/txt) -> load_tasks")
    # Past the recursion limit of json and of PyYAML (whose parser is quadratic in the depth, so
    # a deep case costs ~0.5 s: one in twenty).
    text = "[" * deep + text
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"tasks{suffix}"
        path.write_bytes(text.encode("utf-8", "surrogatepass"))
        try:
            tasks = load_tasks(path)
        except InputError as exc:
            assert str(exc).startswith(str(path)), "the refusal names the file"
            return
        # Whatever loads obeys the same rules as the API's task lists.
        assert 1 <= len(tasks) <= MAX_TASKS and len(set(tasks)) == len(tasks)
        assert all(isinstance(t, str) and t.strip() and len(t) <= MAX_TASK_CHARS for t in tasks)
