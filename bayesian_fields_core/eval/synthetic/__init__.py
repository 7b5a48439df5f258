"""Synthetic benchmark scenes with ground truth: a room, a table, objects from the vocabulary.

`generate_scene(out_dir, spec)` writes a full scene folder (splat, cameras as transforms.json and
COLMAP text, rendered images, tasks.yaml, gt.json + gt_gaussians.npz); `load_ground_truth` reads
the GT back; `suite_specs()` lists the eval suite's scenes. Command line:
``python -m bayesian_fields_core.eval.synthetic OUT --seed N [--n-objects K ...]``.
"""

from __future__ import annotations

from pathlib import Path

from bayesian_fields_core.eval.synthetic.builder import build_scene
from bayesian_fields_core.eval.synthetic.ground_truth import GroundTruth, GTObject, GTTask, load_ground_truth
from bayesian_fields_core.eval.synthetic.pieces import Instance, SyntheticScene
from bayesian_fields_core.eval.synthetic.spec import SceneSpec, suite_specs


def generate_scene(
    out_dir: str | Path,
    spec: SceneSpec | None = None,
    *,
    device: str = "cpu",
    images_from: str | Path | None = None,
) -> Path:
    """See `generate.generate_scene` (imported lazily: it pulls in the renderer and torch)."""
    from bayesian_fields_core.eval.synthetic.generate import generate_scene as _generate

    return _generate(out_dir, spec, device=device, images_from=images_from)


def load_clio_boxes(folder: str | Path) -> list:
    """The scene's GT as `eval.clio.GTObject`s (task, oriented box), one per (task, object)."""
    from bayesian_fields_core.eval.clio import GTObject as ClioGT
    from bayesian_fields_core.geometry.obb import OrientedBox

    gt = load_ground_truth(folder)
    return [
        ClioGT(task=t.text, box=OrientedBox(o.center, o.rotation, o.extents))
        for t in gt.tasks
        for o in t.objects
    ]


def main(argv: list[str] | None = None) -> int:
    from bayesian_fields_core.eval.synthetic.__main__ import main as _main

    return _main(argv)


__all__ = [
    "GTObject",
    "GTTask",
    "GroundTruth",
    "Instance",
    "SceneSpec",
    "SyntheticScene",
    "build_scene",
    "generate_scene",
    "load_clio_boxes",
    "load_ground_truth",
    "main",
    "suite_specs",
]
