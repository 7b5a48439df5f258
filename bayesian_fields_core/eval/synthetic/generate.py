"""Write a complete synthetic scene folder: splat, cameras in two formats, images, tasks, GT.

Layout (everything a user would hand over, plus ground truth):
  point_cloud.ply          INRIA layout
  transforms.json          nerfstudio cameras       sparse/0/*.txt  the same cameras as COLMAP text
  images/frame_00000.png   rendered by the project's renderer
  tasks.yaml               {tasks: [{task, granularity}, ...]}
  gt.json, gt_gaussians.npz  see ground_truth.py
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from bayesian_fields_core.eval.synthetic.builder import build_scene
from bayesian_fields_core.eval.synthetic.cameras import capture_frames
from bayesian_fields_core.eval.synthetic.ground_truth import write_ground_truth
from bayesian_fields_core.eval.synthetic.outliers import outlier_views
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.synthetic.tasks import make_tasks
from bayesian_fields_core.render import GaussianRenderer
from bayesian_fields_core.scene.colmap import write_colmap_text
from bayesian_fields_core.scene.nerfstudio import write_transforms
from bayesian_fields_core.scene.ply import write_ply


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """Float RGB in [0, 1] to 8-bit, rounding to nearest."""
    return np.rint(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def _same_scene_without_outliers(spec: SceneSpec, folder: Path) -> bool:
    """Whether `folder` holds the scene of `spec` with the outlier dial off (its gt.json's spec is
    `spec`'s apart from the name and the dial), so its other frames' images are this one's."""
    try:
        theirs = json.loads((folder / "gt.json").read_text())["spec"]
    except (OSError, ValueError, KeyError):
        return False
    ours = SceneSpec.model_validate(theirs).model_copy(
        update={"name": spec.name, "outlier_share": spec.outlier_share}
    )
    return ours == spec


def generate_scene(
    out_dir: str | Path,
    spec: SceneSpec | None = None,
    *,
    device: str = "cpu",
    images_from: str | Path | None = None,
) -> Path:
    """Generate the scene described by spec (default SceneSpec()) into out_dir; returns out_dir.

    Deterministic: the same spec gives the same arrays and files. Separate seeded streams for
    geometry, cameras and tasks, so changing n_frames does not move the objects.

    `images_from`: a generated folder of the same scene with the outlier dial off; the frames the
    dial did not replace (same splat, same pose) copy its images instead of rendering them again.
    Ignored when that folder holds another scene.
    """
    spec = spec or SceneSpec()
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    scene = build_scene(spec)
    frames = capture_frames(spec, scene)
    tasks = make_tasks(spec, scene.instances, np.random.default_rng([spec.seed, 2]))
    views = outlier_views(spec, scene, len(frames))
    replaced = {v.index for v in views}
    source = Path(images_from) if images_from is not None else None
    if source is not None and (spec.outlier_share == 0 or not _same_scene_without_outliers(spec, source)):
        source = None
    renderer = GaussianRenderer(scene.gaussians, device=device)
    for i, frame in enumerate(frames):
        if source is not None and i not in replaced and (source / "images" / frame.name).is_file():
            frame.image_path = out / "images" / frame.name
            shutil.copyfile(source / "images" / frame.name, frame.image_path)
            continue
        rgb = renderer.render(
            frame.K, frame.world_to_camera, frame.width, frame.height, background=spec.background
        ).rgb
        frame.image_path = out / "images" / frame.name
        assert rgb is not None  # a colour render
        Image.fromarray(to_uint8(rgb)).save(frame.image_path, optimize=True)
    write_ply(out / "point_cloud.ply", scene.gaussians)
    write_transforms(out / "transforms.json", frames)
    write_colmap_text(out / "sparse" / "0", frames)
    doc = {"tasks": [{"task": t.text, "granularity": t.granularity} for t in tasks]}
    (out / "tasks.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    write_ground_truth(out, scene, tasks, [v.to_json() for v in views])
    return out
