"""Labelled masked crops of the synthetic vocabulary, for training and testing the tiny CLIP.

Two sources, both cropped by the pipeline's own `perception.crops.mask_crops`, so the model sees
the same kind of input at training time as in the pipeline:
- single objects rendered alone from random viewpoints, distances and resolutions (mask = alpha);
- whole synthetic scenes seen from random cameras, with masks from the GT id images: objects
  with real occlusions and clipping, and background segments (table, floor, wall), sometimes cut
  to a random window the way an over-segmenter splits large surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.eval.synthetic.builder import build_scene, surfels_to_gaussians
from bayesian_fields_core.eval.synthetic.cameras import look_at, pinhole
from bayesian_fields_core.eval.synthetic.generate import to_uint8
from bayesian_fields_core.eval.synthetic.id_images import IdImageRenderer
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.vocabulary import COLOURS, KINDS, NEUTRALS, sample_part
from bayesian_fields_core.perception.crops import mask_crops
from bayesian_fields_core.render import GaussianRenderer


@dataclass(frozen=True)
class LabelledCrop:
    """A uint8 masked crop and what it shows (colour None for background kinds)."""

    image: np.ndarray
    colour: str | None
    kind: str


def _random_eye(
    rng: np.random.Generator, target: np.ndarray, distance: float, elevation: tuple[float, float]
) -> np.ndarray:
    az = rng.uniform(0.0, 2 * np.pi)
    el = np.deg2rad(rng.uniform(*elevation))
    return target + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def object_crops(
    rng: np.random.Generator,
    n_objects: int,
    views_per_object: int = 4,
    *,
    density: float = 15000.0,
    side_range: tuple[int, int] = (24, 80),
    min_area: int = 30,
) -> list[LabelledCrop]:
    """Crops of single objects (uniform over colour x kind) from random viewpoints and scales."""
    spec = SceneSpec()
    out: list[LabelledCrop] = []
    colours, kinds = list(COLOURS), list(KINDS)
    fov = 40.0
    for _ in range(n_objects):
        colour, kind = colours[rng.integers(len(colours))], kinds[rng.integers(len(kinds))]
        pts, nrm, rgb = [], [], []
        for part in KINDS[kind](float(rng.uniform(*spec.size_range))):
            p, n = sample_part(rng, part, density)
            pts.append(p)
            nrm.append(n)
            rgb.append(
                np.broadcast_to(COLOURS[colour] if part.colour == "main" else NEUTRALS[part.colour], p.shape)
            )
        points = np.concatenate(pts)
        sigma = np.full(len(points), spec.tangential_scale / np.sqrt(density))
        g = surfels_to_gaussians(points, np.concatenate(nrm), np.concatenate(rgb), sigma, spec, rng)
        renderer = GaussianRenderer(g)
        centre = (points.min(0) + points.max(0)) / 2
        radius = float(np.linalg.norm(points - centre, axis=1).max())
        for _ in range(views_per_object):
            side = int(rng.integers(*side_range))
            fill = rng.uniform(0.45, 0.95)
            distance = radius / np.tan(np.deg2rad(fov) / 2) / fill
            w2c = look_at(
                _random_eye(rng, centre, distance, (5.0, 70.0)), centre + rng.normal(0, 0.1 * radius, 3)
            )
            res = renderer.render(pinhole(side, side, fov), w2c, side, side, background=(0.5, 0.5, 0.5))
            labels = np.where(res.alpha > 0.5, 0, -1).astype(np.int32)
            if (labels == 0).sum() >= min_area:
                out.append(LabelledCrop(mask_crops(to_uint8(res.rgb), labels)[0], colour, kind))
    return out


def _cut(rng: np.random.Generator, mask: np.ndarray) -> np.ndarray:
    """The mask restricted to a random window (half to all of its box on each axis)."""
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    h = max(1, int((y1 - y0) * rng.uniform(0.4, 1.0)))
    w = max(1, int((x1 - x0) * rng.uniform(0.4, 1.0)))
    top, left = y0 + rng.integers(0, y1 - y0 - h + 1), x0 + rng.integers(0, x1 - x0 - w + 1)
    window = np.zeros_like(mask)
    window[top : top + h, left : left + w] = True
    return mask & window


def scene_crops(
    rng: np.random.Generator,
    n_scenes: int,
    views_per_scene: int,
    *,
    width: int = 128,
    height: int = 96,
    min_area: int = 40,
    cut_probability: float = 0.5,
) -> list[LabelledCrop]:
    """Object and background crops from random views of random scenes, masks from id images."""
    out: list[LabelledCrop] = []
    for _ in range(n_scenes):
        spec = SceneSpec(
            seed=int(rng.integers(1 << 30)),
            n_objects=int(rng.integers(6, 12)),
            n_duplicates=1,
            n_colours=len(COLOURS),
            object_density=12000.0,
            table_density=1500.0,
            room_density=300.0,
        )
        scene = build_scene(spec)
        renderer = GaussianRenderer(scene.gaussians)
        ids = IdImageRenderer(scene.gaussians, scene.instance_ids)
        K = pinhole(width, height, 60.0)
        for _ in range(views_per_scene):
            target = scene.table_top_center + np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4), 0.0])
            eye = _random_eye(rng, target, rng.uniform(0.6, 1.6), (20.0, 60.0))
            w2c = look_at(eye, target)
            rgb = to_uint8(renderer.render(K, w2c, width, height, background=spec.background).rgb)
            id_image = ids.render(K, w2c, width, height)
            present, areas = np.unique(id_image[id_image >= 0], return_counts=True)
            for inst_id in present[areas >= min_area]:
                inst = scene.instances[int(inst_id)]
                mask = id_image == inst_id
                if inst.category == "background" and rng.uniform() < cut_probability:
                    mask = _cut(rng, mask)
                if mask.sum() < min_area:
                    continue
                labels = np.where(mask, 0, -1).astype(np.int32)
                out.append(LabelledCrop(mask_crops(rgb, labels)[0], inst.colour, inst.kind))
    return out
