"""The sample scene through `bfields run` once per splat format, each file made from the sample's
PLY by the ecosystem's own tools (tests/fixtures/formats/README.md) or, where none writes the
format, by the format's library or our writer: every format gives the PLY's objects.

The runs share one cache folder, so perception (segmentation + CLIP, keyed on the images) runs
once; only visibility and clustering follow the splat. Five frames (frame_stride 4) keep it short.
Formats that quantise (compressed PLY, SPZ, SOG, .splat) or reorder (compressed PLY and SOG sort
by Morton code) the Gaussians are matched to the PLY's Gaussians by position, and object ids
are compared after mapping each object to the PLY object sharing most of its Gaussians (ids are
labels: the same clusters may carry other numbers).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.formats.antimatter import write_antimatter
from bayesian_fields_core.scene.ply import read_ply
from tests.core.scene.format_writers import write_gsplat_checkpoint, write_rgb_ply

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "samples" / "tabletop"
FIXTURES = ROOT / "tests" / "fixtures" / "formats"
PARAMS = ["frame_stride=4", "alignment_check=false", "previews=false", "export_ply=false"]
MIN_SAME_IDS = 0.99
MIN_TOP_IOU = 0.9
"""The Gaussians of each task's best object, against the PLY run's (quantisation may move a few)."""


def _ply_copy(scene: Path) -> None:
    shutil.copy(SAMPLE / "point_cloud.ply", scene / "point_cloud.ply")


def _fixture(name: str):  # noqa: ANN202
    def place(scene: Path) -> None:
        source = FIXTURES / name
        if source.is_dir():
            shutil.copytree(source, scene / name)
        else:
            shutil.copy(source, scene / name)

    return place


def _written(writer, name: str):  # noqa: ANN001, ANN202
    def place(scene: Path) -> None:
        writer(scene / name, read_ply(SAMPLE / "point_cloud.ply"))

    return place


FORMATS = {
    "ply": _ply_copy,
    "compressed.ply": _fixture("tabletop.compressed.ply"),
    "spz v4": _fixture("tabletop.spz"),
    "spz v3": _fixture("tabletop.v3.spz"),
    "sog": _fixture("tabletop.sog"),
    "sog folder": _fixture("tabletop_sog"),
    "glb": _fixture("tabletop.glb"),
    "splat": _written(write_antimatter, "tabletop.splat"),
    "rgb ply": _written(write_rgb_ply, "tabletop.ply"),
    "gsplat ckpt": _written(write_gsplat_checkpoint, "ckpt_29999.pt"),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("formats")


def _run(fmt: str, root: Path) -> tuple[np.ndarray, np.ndarray, object]:
    """(object ids, Gaussian means in the file's order, result) of one format's run."""
    scene = root / fmt.replace(" ", "_")
    if not (scene / "out" / "result").is_dir():
        scene.mkdir()
        shutil.copytree(SAMPLE / "images", scene / "images")
        shutil.copy(SAMPLE / "transforms.json", scene / "transforms.json")
        FORMATS[fmt](scene)
        if fmt == "sog folder":  # the folder's meta.json is the splat
            (scene / "tabletop_sog" / "meta.json").rename(scene / "meta.json")
            for image in (scene / "tabletop_sog").iterdir():
                image.rename(scene / image.name)
            (scene / "tabletop_sog").rmdir()
        args = ["run", str(scene), "--tasks", str(SAMPLE / "tasks.yaml"), "--out", str(scene / "out")]
        args += ["--cache-dir", str(root / "cache"), "-q"]
        for param in PARAMS:
            args += ["--param", param]
        assert main(args) == 0
    result = read_result(scene / "out" / "result")
    from bayesian_fields_core.scene.loader import load_scene

    means = load_scene(scene).gaussians.means
    return np.asarray(result.object_ids).astype(np.int64), means, result


def agreement(ids: np.ndarray, ref_ids: np.ndarray) -> float:
    """Share of Gaussians whose object, mapped to the reference object sharing most of its
    Gaussians, is the reference's object."""
    mapped = ids.copy()
    for obj in np.unique(ids):
        members = ids == obj
        values, counts = np.unique(ref_ids[members], return_counts=True)
        mapped[members] = values[np.argmax(counts)]
    return float((mapped == ref_ids).mean())


def top_sets(result: object, ids: np.ndarray) -> list[set[int]]:
    """Per task, the Gaussians (indices) of its best object."""
    return [
        set(np.flatnonzero(ids == chosen[0].object_id).tolist()) if chosen else set()
        for chosen in result.selections.values()
    ]


@pytest.mark.parametrize("fmt", [f for f in FORMATS if f != "ply"])
def test_format_gives_the_objects_of_its_ply(fmt: str, runs: Path) -> None:
    ref_ids, ref_means, ref = _run("ply", runs)
    ids, means, result = _run(fmt, runs)
    assert len(ids) == len(ref_ids)
    # The Gaussian of this file at each PLY Gaussian's position (quantised formats move them by
    # at most a few mm in this 4-unit scene).
    distance, order = cKDTree(means).query(ref_means)
    assert distance.max() < 0.01, distance.max()
    ids = ids[order]
    same = agreement(ids, ref_ids)
    ref_top = top_sets(ref, ref_ids)
    top = [
        {int(i) for i in np.flatnonzero(np.isin(order, list(s)))}
        for s in top_sets(result, np.asarray(result.object_ids))
    ]
    # a task neither run found (no object above the threshold) agrees
    overlaps = [len(a & b) / len(a | b) if a | b else 1.0 for a, b in zip(top, ref_top, strict=True)]
    print(f"{fmt}: {same:.2%} same objects, top-object IoU per task {np.round(overlaps, 3).tolist()}")
    assert same >= MIN_SAME_IDS, (same, overlaps)
    assert all(o >= MIN_TOP_IOU for o in overlaps), overlaps  # every task's top answer is the PLY's
