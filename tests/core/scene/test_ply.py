"""PLY reading/writing: bit-exact round trips, the INRIA SH layout, cross-checks with plyfile, errors."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.ply import read_ply, read_ply_header, write_ply

from .conftest import random_gaussians


def assert_identical(a, b) -> None:
    for attr in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        x, y = getattr(a, attr), getattr(b, attr)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape
        assert x.tobytes() == y.tobytes(), attr
    assert list(a.extra) == list(b.extra)
    for name in a.extra:
        assert a.extra[name].dtype == b.extra[name].dtype, name
        assert a.extra[name].tobytes() == b.extra[name].tobytes(), name


@pytest.mark.parametrize("ascii", [False, True])
@pytest.mark.parametrize("degree", [0, 3])
def test_round_trip_is_bit_identical(tmp_path, ascii, degree):
    g = random_gaussians(257, degree, seed=degree)
    path = tmp_path / "s.ply"
    write_ply(path, g, ascii=ascii)
    back = read_ply(path)
    assert back.sh_degree == degree
    assert_identical(g, back)
    header = read_ply_header(path)
    assert header.format == ("ascii" if ascii else "binary_little_endian")
    assert header.count == 257 and header.sh_degree == degree


def test_written_file_follows_inria_layout(tmp_path):
    """plyfile (an independent reader) sees the INRIA property order and channel-major f_rest."""
    g = random_gaussians(10, 3, extra=False)
    path = tmp_path / "s.ply"
    write_ply(path, g)
    v = PlyData.read(str(path))["vertex"]
    names = [p.name for p in v.properties]
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert names[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    # f_rest index c * 15 + j holds coefficient j + 1 of channel c.
    np.testing.assert_array_equal(v["f_rest_17"], g.sh[:, 1 + 2, 1])
    np.testing.assert_array_equal(v["f_rest_44"], g.sh[:, 15, 2])
    np.testing.assert_array_equal(v["rot_0"], g.quats[:, 0])
    np.testing.assert_array_equal(v["nx"], 0.0)  # normals written as zeros when absent


def write_with_plyfile(path, n=6, *, byte_order="<", text=False, drop=(), degree=1, types=None):
    """A splat file produced by plyfile, with f_rest_i = 100 + i so the SH mapping is checkable."""
    k = (degree + 1) ** 2
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "label"]
    names = [nm for nm in names if nm not in drop]
    types = types or {}
    dtype = [(nm, types.get(nm, "u1" if nm == "label" else "f4")) for nm in names]
    data = np.zeros(n, dtype=dtype)
    for i, nm in enumerate(names):
        data[nm] = (100 + int(nm[7:])) if nm.startswith("f_rest_") else i + np.arange(n)
    PlyData([PlyElement.describe(data, "vertex")], text=text, byte_order=byte_order).write(str(path))
    return data


@pytest.mark.parametrize(("byte_order", "text"), [("<", False), (">", False), ("=", True)])
def test_reads_files_written_by_plyfile(tmp_path, byte_order, text):
    path = tmp_path / "p.ply"
    data = write_with_plyfile(path, byte_order=byte_order, text=text)
    g = read_ply(path)
    assert g.sh_degree == 1 and len(g) == 6
    np.testing.assert_array_equal(g.means[:, 1], data["y"])
    np.testing.assert_array_equal(g.quats[:, 3], data["rot_3"])
    # channel c, coefficient j (1-based j+1) comes from f_rest_{c*3 + j} = 100 + c*3 + j
    expected = 100 + np.arange(3)[None, :] * 3 + np.arange(3)[:, None]  # (j, c)
    np.testing.assert_array_equal(g.sh[0, 1:, :], expected)
    assert g.extra["label"].dtype == np.uint8
    np.testing.assert_array_equal(g.extra["label"], data["label"])


def test_double_precision_properties_are_accepted(tmp_path):
    path = tmp_path / "d.ply"
    data = write_with_plyfile(path, types={"x": "f8", "opacity": "f8"})
    g = read_ply(path)
    assert g.means.dtype == np.float32
    np.testing.assert_array_equal(g.means[:, 0], data["x"].astype(np.float32))


def error_message(path, **kwargs) -> str:
    with pytest.raises(InputError) as info:
        read_ply(path, **kwargs)
    message = str(info.value)
    assert str(path) in message
    return message


def test_not_a_ply(tmp_path):
    path = tmp_path / "x.ply"
    path.write_bytes(b"GIF89a...")
    assert "not a PLY" in error_message(path)


def test_no_vertex_element(tmp_path):
    path = tmp_path / "x.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement face 0\nproperty float a\nend_header\n")
    assert "no 'vertex' element" in error_message(path)


def test_missing_properties_are_named(tmp_path):
    path = tmp_path / "x.ply"
    write_with_plyfile(path, drop=("opacity", "rot_2"))
    message = error_message(path)
    assert "missing required vertex properties" in message and "opacity, rot_2" in message


def test_non_float_required_property(tmp_path):
    path = tmp_path / "x.ply"
    write_with_plyfile(path, types={"scale_1": "i4"})
    assert "scale_1 (int)" in error_message(path)


def test_bad_sh_coefficient_count(tmp_path):
    path = tmp_path / "x.ply"
    write_with_plyfile(path, drop=("f_rest_8",))
    assert "8 f_rest_* properties" in error_message(path)


def test_truncated_body(tmp_path):
    path = tmp_path / "x.ply"
    write_with_plyfile(path, n=6)
    raw = path.read_bytes()
    path.write_bytes(raw[:-10])
    stride = 4 * 23 + 1  # 23 float properties + the uchar label
    message = error_message(path)
    assert f"expected 6 x {stride} = {6 * stride} bytes, got {6 * stride - 10}" in message
    with pytest.raises(InputError, match="truncated"):
        read_ply_header(path)


def test_absurd_vertex_count(tmp_path):
    path = tmp_path / "x.ply"
    write_with_plyfile(path, n=6)
    raw = path.read_bytes().replace(b"element vertex 6", b"element vertex 900000000", 1)
    path.write_bytes(raw)
    assert "exceeds the limit max_gaussians=20000000" in error_message(path)
    # within the limit, the count is still impossible for the file's size
    assert "truncated" in error_message(path, max_gaussians=10**9)
    assert "max_gaussians=5" in error_message(tmp_path / "x.ply", max_gaussians=5)


def test_ascii_count_inconsistent_with_size(tmp_path):
    path = tmp_path / "x.ply"
    write_with_plyfile(path, n=3, text=True)
    path.write_bytes(path.read_bytes().replace(b"element vertex 3", b"element vertex 3000", 1))
    assert "inconsistent with the file size" in error_message(path)


def test_non_finite_values_are_counted_per_property(tmp_path):
    g = random_gaussians(50, 1, extra=False)
    g.means[[3, 7], 1] = np.nan
    g.sh[4, 2, 0] = np.inf  # channel 0, coefficient 2 -> f_rest_1
    path = tmp_path / "x.ply"
    write_ply(path, g)
    message = error_message(path)
    assert "3 non-finite values" in message and "2 in y" in message and "1 in f_rest_1" in message


def test_header_only_validation_does_not_read_values(tmp_path):
    g = random_gaussians(20, 2, extra=False)
    g.means[0, 0] = np.nan
    path = tmp_path / "x.ply"
    write_ply(path, g)
    header = read_ply_header(path)
    assert header.count == 20 and header.sh_degree == 2 and header.format == "binary_little_endian"
    assert [n for n, _ in header.properties][:3] == ["x", "y", "z"]
