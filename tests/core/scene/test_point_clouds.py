"""A PLY of plain points (COLMAP's points3D as PLY, an SfM or lidar cloud) is not a splat
(issue 45): it was told to run `splat-transform` on it, which refuses it, and the loader took
`point_cloud.ply` again anyway. Now the loader passes over a point cloud when a trained splat is
beside it and otherwise refuses in one line saying what the file is and how to get a splat."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.loader import find_splat
from bayesian_fields_core.scene.ply import read_ply_header, write_ply

from .conftest import random_gaussians


def xyz_cloud(path: Path, n: int = 200) -> Path:
    """An xyz-only PLY, as a lidar tool or `points3D` -> PLY with nothing else writes it."""
    rows = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    rows["x"], rows["y"], rows["z"] = np.random.default_rng(0).normal(size=(3, n))
    plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")]).write(path)
    return path


def colmap_cloud(path: Path, n: int = 200) -> Path:
    """COLMAP's `model_converter --output_type PLY`: x y z nx ny nz (float), red green blue (uchar)."""
    fields = [(a, "f4") for a in ("x", "y", "z", "nx", "ny", "nz")] + [
        (c, "u1") for c in ("red", "green", "blue")
    ]
    rows = np.zeros(n, dtype=fields)
    rows["x"], rows["y"], rows["z"] = np.random.default_rng(1).normal(size=(3, n))
    rows["red"] = 180
    plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")]).write(path)
    return path


CLOUDS = {"xyz": xyz_cloud, "xyz+normals+rgb": colmap_cloud}


def _assert_point_cloud_message(message: str, cloud: Path) -> None:
    assert message.startswith(f"{cloud}: a point cloud"), message
    assert "not a trained Gaussian splat" in message and "ns-train splatfacto" in message
    assert "simple_trainer" in message and "train.py" in message
    assert "point_cloud/iteration_<N>/point_cloud.ply" in message
    assert "splat-transform" not in message and "\n" not in message


@pytest.mark.parametrize("kind", sorted(CLOUDS))
def test_a_lone_point_cloud_is_refused_with_what_it_is(kind: str, tmp_path: Path) -> None:
    cloud = CLOUDS[kind](tmp_path / "point_cloud.ply")
    with pytest.raises(InputError) as refused:
        find_splat(tmp_path)
    _assert_point_cloud_message(str(refused.value), cloud)
    if kind != "xyz":
        assert "colours, normals" in str(refused.value)
    with pytest.raises(InputError) as read:  # the reader itself, as an upload or `bfields view` meets it
        read_ply_header(cloud)
    _assert_point_cloud_message(str(read.value), cloud)


@pytest.mark.parametrize("kind", sorted(CLOUDS))
def test_a_trained_splat_beside_a_point_cloud_is_the_splat(kind: str, tmp_path: Path) -> None:
    cloud = CLOUDS[kind](tmp_path / "point_cloud.ply")
    write_ply(tmp_path / "splat.ply", random_gaussians(50, 0))
    assert find_splat(tmp_path) == tmp_path / "splat.ply"

    (tmp_path / "splat.ply").unlink()  # 3DGS's own output folder beside the cloud
    trained = tmp_path / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    trained.parent.mkdir(parents=True)
    write_ply(trained, random_gaussians(50, 1))
    assert find_splat(tmp_path) == trained

    other = tmp_path / "other"  # no preferred names: the one trained file among the .ply files
    other.mkdir()
    cloud.rename(other / "points3D.ply")
    write_ply(other / "garden.ply", random_gaussians(50, 0))
    assert find_splat(other) == other / "garden.ply"


def test_a_splat_with_normals_and_colours_is_still_a_splat(tmp_path: Path) -> None:
    """3DGS's own PLY carries nx ny nz (zeros) and some exporters add red/green/blue."""
    write_ply(tmp_path / "point_cloud.ply", random_gaussians(50, 0, extra=True))
    assert find_splat(tmp_path) == tmp_path / "point_cloud.ply"
