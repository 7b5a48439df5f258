"""Content tests for the splat formats that share a file name ending (the `.ply` family).

A `.ply` may be an INRIA splat, a PlayCanvas compressed PLY or an RGB-coloured PLY; only the
header tells. `registry.detect` asks these in table order; each reads the header (a few hundred
bytes) through the readers' boundary, so a broken header is an InputError naming the file.
"""

from __future__ import annotations

from pathlib import Path

from bayesian_fields_core.errors import input_boundary


def _vertex_elements(path: Path) -> list[tuple[str, int, list]]:
    from bayesian_fields_core.scene.formats import READER_FAILURES
    from bayesian_fields_core.scene.ply import read_ply_elements

    with input_boundary(str(path), what="cannot read PLY header", extra=READER_FAILURES):
        _, elements, _ = read_ply_elements(path)
    return elements


def is_compressed_ply_file(path: Path) -> bool:
    """A PlayCanvas compressed PLY (`packed_*` vertex properties, a chunk element)."""
    from bayesian_fields_core.scene.formats.compressed_ply import is_compressed_ply

    return is_compressed_ply(_vertex_elements(path))


def is_rgb_ply_file(path: Path) -> bool:
    """A PLY coloured by red/green/blue instead of SH coefficients (and not compressed)."""
    from bayesian_fields_core.scene.formats.compressed_ply import is_compressed_ply
    from bayesian_fields_core.scene.formats.ply_rgb import is_rgb_splat

    elements = _vertex_elements(path)
    names = {p[0] for name, _, props in elements if name == "vertex" for p in props}
    return not is_compressed_ply(elements) and is_rgb_splat(names)


def point_cloud_properties(path: Path) -> set[str] | None:
    """The vertex property names of `path` when it is a PLY of plain points (a point cloud, not
    a splat: `scene.point_cloud`), else None; also None for a header that cannot be read, which
    the splat reader then reports in its own words."""
    from bayesian_fields_core.errors import InputError
    from bayesian_fields_core.scene.point_cloud import is_point_cloud

    if not (path.is_file() and path.name.lower().endswith(".ply")):
        return None
    try:
        elements = _vertex_elements(path)
    except InputError:
        return None
    names = {p[0] for name, _, props in elements if name == "vertex" for p in props}
    return names if is_point_cloud(names) else None
