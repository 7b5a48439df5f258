"""A PLY of plain points (a point cloud) is not a Gaussian splat: recognise it and say so.

Why: COLMAP's `points3D` converted to PLY, an SfM or a lidar cloud is often named
`point_cloud.ply`, the first name the loader looks for. Its vertices have positions (and maybe
colours and normals) but none of a splat's per-Gaussian properties, and no converter turns one
into the other (`splat-transform` refuses it: "Unsupported data in file"); a splat has to be
trained from the capture. So the loader passes over a point cloud when a trained splat is beside
it, and refuses a folder whose only candidate is one with what to do instead.
"""

from __future__ import annotations

MEANS = ("x", "y", "z")
GAUSSIAN_PROPERTIES = ("opacity", "scale_0", "rot_0", "f_dc_0", "packed_position")
"""One property of each kind a splat PLY has (INRIA, RGB or compressed layout); a point cloud
has none of them."""

POINT_CLOUD_MESSAGE = (
    "a point cloud (positions{extras}, no opacity, scales, rotations or SH colours: for instance "
    "COLMAP's points3D or an SfM or lidar cloud), not a trained Gaussian splat; train a splat from "
    "the capture (nerfstudio `ns-train splatfacto`, gsplat's simple_trainer or 3DGS's train.py) "
    "and point bfields at the result (the run folder, point_cloud/iteration_<N>/point_cloud.ply "
    "or the exported splat)"
)


def is_point_cloud(names: set[str]) -> bool:
    """Vertex property names of a point cloud: x, y, z and no Gaussian property."""
    return set(MEANS) <= names and not names & set(GAUSSIAN_PROPERTIES)


def point_cloud_message(names: set[str]) -> str:
    """The one-line refusal for a point cloud with these vertex properties."""
    extras = [
        what
        for what, props in (("colours", {"red", "green", "blue"}), ("normals", {"nx", "ny", "nz"}))
        if props <= names
    ]
    return POINT_CLOUD_MESSAGE.format(extras="".join(f", {e}" for e in extras))
