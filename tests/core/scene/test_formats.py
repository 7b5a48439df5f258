"""Each splat format read into the PLY's frame and parameterisation: the fixtures were made from
the sample's PLY by `splat-transform` (tests/fixtures/formats/README.md), so every reader must give
back the PLY's Gaussians within the format's quantisation; and bad files are refused in one line
that names the file and, where we read nothing, the command that converts it."""

from __future__ import annotations

import json
import logging
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats import check_upload_name, read_splat, splat_format
from bayesian_fields_core.scene.formats.antimatter import write_antimatter
from bayesian_fields_core.scene.loader import find_splat
from bayesian_fields_core.scene.ply import read_ply
from bayesian_fields_core.scene.types import Gaussians

from .format_writers import sh3_sample, write_gsplat_checkpoint, write_rgb_ply

ROOT = Path(__file__).resolve().parents[3]
PLY = ROOT / "samples" / "tabletop" / "point_cloud.ply"
FIXTURES = ROOT / "tests" / "fixtures" / "formats"
LIMIT = 10_000_000

# (fixture, kind, largest position error, largest log-scale error, opacity error, DC error)
CASES = [
    ("tabletop.compressed.ply", "compressed_ply", 3e-3, 0.01, 0.005, 0.02),
    ("tabletop.spz", "spz", 2e-4, 0.04, 0.005, 0.02),
    ("tabletop.v3.spz", "spz", 2e-4, 0.04, 0.005, 0.02),
    ("tabletop.sog", "sog", 3e-3, 0.1, 0.005, 0.05),
    ("tabletop_sog/meta.json", "sog", 3e-3, 0.1, 0.005, 0.05),
    ("tabletop.glb", "gltf", 1e-6, 1e-5, 1e-5, 1e-6),
]


def covariances(g: Gaussians) -> np.ndarray:
    q = g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True)
    w, x, y, z = q.T.astype(np.float64)
    r = np.stack(
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1,
    ).reshape(-1, 3, 3)  # fmt: skip
    s = np.exp(2 * g.log_scales.astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", r, s, r)


def assert_same_splat(
    g: Gaussians, ref: Gaussians, pos: float, scale: float, opacity: float, dc: float
) -> None:
    """`g` is `ref` (in any order) within the tolerances; covariances (what renders) within 10%.

    Reordered formats are matched by position; a few Gaussians of the sample share a position,
    so the attributes are compared on 99.9% of them and the positions on all."""
    assert len(g) == len(ref)
    distance, order = cKDTree(g.means).query(ref.means)
    assert distance.max() <= pos, distance.max()
    g = g.subset(order)

    def most(values: np.ndarray) -> float:
        return float(np.quantile(np.abs(values).reshape(len(values), -1).max(axis=1), 0.999))

    assert most(g.log_scales - ref.log_scales) <= scale
    assert most(g.opacities - ref.opacities) <= opacity
    assert most(g.sh[:, 0] - ref.sh[:, 0]) <= dc
    a, b = covariances(g), covariances(ref)
    rel = np.abs(a - b).max(axis=(1, 2)) / np.abs(b).max(axis=(1, 2))
    assert np.median(rel) < 0.05 and most(rel) < 0.1, (np.median(rel), most(rel))


@pytest.fixture(scope="module")
def ply() -> Gaussians:
    return read_ply(PLY)


@pytest.mark.parametrize(("name", "kind", "pos", "scale", "opacity", "dc"), CASES)
def test_fixture_reads_as_its_ply(name: str, kind: str, pos: float, scale: float, opacity: float, dc: float, ply: Gaussians) -> None:  # fmt: skip
    path = FIXTURES / name
    assert splat_format(path) == kind
    assert_same_splat(read_splat(path, max_gaussians=LIMIT), ply, pos, scale, opacity, dc)


def test_spz_versions_and_sog_containers_agree() -> None:
    v4, v3 = (read_splat(FIXTURES / n, max_gaussians=LIMIT) for n in ("tabletop.spz", "tabletop.v3.spz"))
    np.testing.assert_array_equal(v4.means, v3.means)
    np.testing.assert_array_equal(v4.quats, v3.quats)
    zipped, folder = (read_splat(FIXTURES / n, max_gaussians=LIMIT) for n in ("tabletop.sog", "tabletop_sog"))
    np.testing.assert_array_equal(zipped.means, folder.means)


def test_written_formats_read_back(tmp_path: Path, ply: Gaussians, caplog: pytest.LogCaptureFixture) -> None:
    write_antimatter(tmp_path / "a.splat", ply)
    assert_same_splat(read_splat(tmp_path / "a.splat", max_gaussians=LIMIT), ply, 0, 1e-5, 0.003, 0.01)
    write_rgb_ply(tmp_path / "rgb.ply", ply)
    # the library logger's own level: an earlier CLI run in the same process may have quietened it
    with caplog.at_level(logging.INFO, logger="bayesian_fields_core"):
        rgb = read_splat(tmp_path / "rgb.ply", max_gaussians=LIMIT)
    assert splat_format(tmp_path / "rgb.ply") == "rgb_ply" and rgb.sh_degree == 0
    assert "colour-only splat" in caplog.text and "renders flatter" in caplog.text
    assert_same_splat(rgb, ply, 0, 0, 0, 0.01)
    write_gsplat_checkpoint(tmp_path / "ckpt_100.pt", ply)
    assert_same_splat(read_splat(tmp_path / "ckpt_100.pt", max_gaussians=LIMIT), ply, 0, 0, 0, 0)


def test_scene_folders_find_every_format(tmp_path: Path) -> None:
    for name in ("tabletop.compressed.ply", "tabletop.spz", "tabletop.sog", "tabletop.glb"):
        folder = tmp_path / name.replace(".", "_")
        folder.mkdir()
        shutil.copy(FIXTURES / name, folder / name)
        assert find_splat(folder) == folder / name
    sog = tmp_path / "sog_folder"
    shutil.copytree(FIXTURES / "tabletop_sog", sog)
    assert find_splat(sog) == sog / "meta.json"


class NotATensor:
    """Anything but a tensor: a checkpoint holding it must not be unpickled."""


def test_checkpoint_is_read_with_weights_only(tmp_path: Path) -> None:
    import torch

    torch.save({"step": 1, "splats": {"means": NotATensor()}}, tmp_path / "ckpt_1.pt")
    with pytest.raises(
        InputError, match=r"ckpt_1.pt: not a gsplat checkpoint readable with weights_only=True"
    ):
        read_splat(tmp_path / "ckpt_1.pt", max_gaussians=LIMIT)


def refusal(path: Path) -> str:
    with pytest.raises(InputError) as info:
        read_splat(path, max_gaussians=LIMIT)
    message = str(info.value)
    assert "\n" not in message and str(path) in message, message
    return message


def test_bad_files_are_refused_in_one_line(tmp_path: Path, ply: Gaussians) -> None:
    (tmp_path / "x.ksplat").write_bytes(b"\0" * 4096)
    hint = f"npx @playcanvas/splat-transform {tmp_path / 'x.ksplat'} {tmp_path / 'point_cloud.ply'}"
    assert hint in refusal(tmp_path / "x.ksplat")
    (tmp_path / "x.lcc").write_bytes(b"{}")
    assert "convert it first" in refusal(tmp_path / "x.lcc")
    data = (FIXTURES / "tabletop.v3.spz").read_bytes()
    (tmp_path / "cut.spz").write_bytes(data[: len(data) // 2])
    assert "SPZ" in refusal(tmp_path / "cut.spz") or "gzip" in refusal(tmp_path / "cut.spz")
    (tmp_path / "v4cut.spz").write_bytes((FIXTURES / "tabletop.spz").read_bytes()[:40])
    assert "SPZ v4" in refusal(tmp_path / "v4cut.spz")
    (tmp_path / "bad.splat").write_bytes(b"\0" * 33)
    assert "not a multiple of the 32-byte" in refusal(tmp_path / "bad.splat")
    with (
        zipfile.ZipFile(FIXTURES / "tabletop.sog") as src,
        zipfile.ZipFile(tmp_path / "hole.sog", "w") as dst,
    ):
        for item in src.infolist():
            if item.filename != "quats.webp":
                dst.writestr(item, src.read(item))
    assert "SOG archive has no 'quats.webp'" in refusal(tmp_path / "hole.sog")
    # a glTF that is a mesh, not a splat
    doc = json.dumps(
        {"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]}
    )
    body = doc.encode().ljust((len(doc) + 3) // 4 * 4)
    (tmp_path / "mesh.glb").write_bytes(
        b"glTF" + struct.pack("<III", 2, 20 + len(body), len(body)) + b"JSON" + body
    )
    assert "no primitive with the KHR_gaussian_splatting extension" in refusal(tmp_path / "mesh.glb")


def test_the_same_sanity_checks_as_a_ply(tmp_path: Path, ply: Gaussians) -> None:
    broken = ply.subset(np.arange(len(ply)))
    broken.quats[:5] = 0.0
    write_gsplat_checkpoint(tmp_path / "ckpt_1.pt", broken)
    assert "5 Gaussians have a zero-length rotation quaternion" in refusal(tmp_path / "ckpt_1.pt")
    broken.means[:3, 0] = np.nan
    write_gsplat_checkpoint(tmp_path / "ckpt_2.pt", broken)
    assert "non-finite values (NaN or inf): 3 in means" in refusal(tmp_path / "ckpt_2.pt")
    assert "degenerate splat" not in refusal(tmp_path / "ckpt_2.pt")


def test_the_hinted_conversion_is_what_the_next_run_loads(tmp_path: Path) -> None:
    """The refusal's command writes point_cloud.ply beside the .ksplat; with both in the folder
    the loader takes the converted file (a `<stem>.ply` beside it was refused as "several splat
    files"). The conversion itself is splat-transform's (not installed here): a copy of a PLY
    stands in for its output, which is an ordinary INRIA PLY."""
    source = tmp_path / "scene.ksplat"
    source.write_bytes(b"\0" * 4096)
    command = refusal(source).split("convert it first: ")[1].split()
    assert command[:3] == ["npx", "@playcanvas/splat-transform", str(source)]
    shutil.copy(PLY, command[3])
    assert find_splat(tmp_path) == tmp_path / "point_cloud.ply"
    assert len(read_splat(find_splat(tmp_path), max_gaussians=LIMIT)) == len(read_ply(PLY))


def test_upload_names() -> None:
    for ok in ("a.ply", "a.compressed.ply", "a.spz", "a.sog", "a.splat", "a.glb"):
        check_upload_name(ok)
    with pytest.raises(InputError, match=r"does not accept checkpoints \(\.pt\).*bfields submit"):
        check_upload_name("ckpt_29999_rank0.pt")
    with pytest.raises(InputError, match=r"npx @playcanvas/splat-transform scene.ksplat point_cloud.ply"):
        check_upload_name("scene.ksplat")
    with pytest.raises(InputError, match=r"'scene.obj' is not a splat file we read"):
        check_upload_name("scene.obj")


@pytest.mark.parametrize(
    ("name", "step"),
    # the largest error is half a quantisation step: compressed PLY 8/256, SPZ 4-bit bands 1/8
    [("sh3.compressed.ply", 8 / 256), ("sh3.spz", 1 / 8), ("sh3.glb", 1e-6)],
)
def test_sh_bands_decode_and_turn_with_the_axes(name: str, step: float) -> None:
    """SH degree 3 through each format: a wrong band order, sign or axis turn (SPZ and glTF store
    other axes; their bands must turn with them) would err by the bands' own size (0.3)."""
    ref = sh3_sample(PLY)
    g = read_splat(FIXTURES / name, max_gaussians=LIMIT)
    assert g.sh.shape == (2000, 16, 3)
    _, order = cKDTree(g.means).query(ref.means)
    err = np.abs(g.subset(order).sh[:, 1:] - ref.sh[:, 1:])
    assert np.quantile(err, 0.999) <= step / 2 + 1 / 128, np.quantile(err, 0.999)  # + one byte step
