"""`scene.yaml`: a scene folder that says where its parts are, for layouts no rule recognises.

    splat: exports/splat.ply          # the splat .ply (required)
    cameras: sparse/0                 # transforms.json, cameras.json or a COLMAP model folder (required)
    images: images                    # image folder for COLMAP / cameras.json (default: images)
    depth: depth                      # optional: <depth>/<image path without extension>.png|.tif|.npy
    depth_scale: 0.001                # metres (capture units) per stored depth unit
    splat_to_camera: [[...], ...]     # optional 4x4 similarity, splat frame -> camera frame
    transform_file: dataparser_transforms.json   # or: a transform file (see trainer_transforms.py)
    metric: true                      # optional: the cameras' units are metres (RGB-D, ARKit, a scaled SfM)

Every path is relative to the scene folder and must stay inside it (`files.resolve_inside`), so an
uploaded scene.yaml cannot make the service open anything else.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from bayesian_fields_core.errors import InputError

SCENE_YAML = "scene.yaml"
MAX_SCENE_YAML_BYTES = 256 * 1024


class SceneSpecFile(BaseModel):
    """The validated content of a scene.yaml (paths still unresolved)."""

    model_config = ConfigDict(extra="forbid")

    splat: str = Field(
        description="Splat file (.ply or any format of scene/formats), relative to the scene folder."
    )
    cameras: str = Field(description="transforms.json, cameras.json or a COLMAP model folder.")
    images: str | None = Field(None, description="Image folder for COLMAP / cameras.json cameras.")
    depth: str | None = Field(None, description="Folder of depth maps named like the images.")
    depth_scale: float = Field(1.0, gt=0, description="Capture units (metres) per stored depth unit.")
    splat_to_camera: list[list[float]] | None = Field(
        None, description="4x4 similarity from the splat's frame to the cameras' frame."
    )
    transform_file: str | None = Field(
        None, description="A transform file (nerfstudio dataparser_transforms.json or a 4x4 JSON)."
    )
    metric: bool = Field(
        False,
        description=(
            "The cameras' frame is in metres. Only then do reports say 'm'; COLMAP's units are "
            "arbitrary, so nothing else is taken as metric."
        ),
    )


def read_scene_yaml(path: Path) -> SceneSpecFile:
    """Parse and validate a scene.yaml; InputError naming the file and the first bad field."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", source=str(path)) from None
    if len(raw) > MAX_SCENE_YAML_BYTES:
        raise InputError(f"larger than {MAX_SCENE_YAML_BYTES} bytes", source=str(path))
    try:
        doc = yaml.safe_load(raw.decode("utf-8"))
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"cannot parse YAML ({' '.join(str(exc).split())})", source=str(path)) from None
    if not isinstance(doc, dict):
        raise InputError("expected a mapping (splat, cameras, images, ...)", source=str(path))
    try:
        spec = SceneSpecFile.model_validate(doc)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in first["loc"])
        raise InputError(f"{loc}: {first['msg']}", source=str(path)) from None
    if spec.splat_to_camera is not None and spec.transform_file is not None:
        raise InputError("give splat_to_camera or transform_file, not both", source=str(path))
    return spec
