"""Labelled masked crops of the synthetic vocabulary, for training and testing the tiny CLIP.

Two sources, both cropped by the pipeline's own `perception.crops.mask_crops`, so the model sees
the same kind of input at training time as in the pipeline:
- single objects rendered alone from random viewpoints, distances and resolutions (mask = alpha),
  some of them with a coloured label on one side (as `capture.add_labels` gives them), so the
  crop shows the label only when the camera faces it, and some striped (`capture.apply_texture`);
- whole synthetic scenes seen from random cameras, with masks from the GT id images: objects
  with real occlusions and clipping, and background segments (table, floor, wall), sometimes cut
  to a random window the way an over-segmenter splits large surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayesian_fields_core.eval.synthetic.builder import build_scene, paint_label, surfels_to_gaussians
from bayesian_fields_core.eval.synthetic.capture import label_part, stripes
from bayesian_fields_core.eval.synthetic.generate import to_uint8
from bayesian_fields_core.eval.synthetic.id_images import IdImageRenderer
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.vocabulary import (
    COLOURS,
    KINDS,
    LABELLED_KINDS,
    NEUTRALS,
    label_colours,
    sample_part,
)
from bayesian_fields_core.geometry.transforms import look_at, pinhole
from bayesian_fields_core.perception.crops import mask_crops
from bayesian_fields_core.render import GaussianRenderer


@dataclass(frozen=True)
class LabelledCrop:
    """A uint8 masked crop and what it shows (colour None for background kinds; label: the colour
    of the label in sight, None when the object has none or it faces away)."""

    image: np.ndarray
    colour: str | None
    kind: str
    label: str | None = None


def _random_eye(
    rng: np.random.Generator,
    target: np.ndarray,
    distance: float,
    elevation: tuple[float, float],
    azimuth: float | None = None,
) -> np.ndarray:
    az = rng.uniform(0.0, 2 * np.pi) if azimuth is None else azimuth
    el = np.deg2rad(rng.uniform(*elevation))
    return target + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


@dataclass(frozen=True)
class _LabelPatch:
    """A label on a single rendered object: its colour, centre (object coordinates, facing +y)
    and the half-angle within which it reads as its colour."""

    colour: str
    centre: np.ndarray
    half_angle_deg: float

    def seen_from(self, eye: np.ndarray) -> str | None | Literal[False]:
        """The label's colour when it reads clearly from `eye` (at least halfway from the object's
        colour to the label's), None when it shows the object's colour, False in between (an
        ambiguous view that training leaves out)."""
        direction = (eye - self.centre) / np.linalg.norm(eye - self.centre)
        cos_h = np.cos(np.deg2rad(self.half_angle_deg))
        blend = (direction[1] - cos_h) / (1.0 - cos_h)
        if blend >= 0.5:
            return self.colour
        return None if blend <= 0.0 else False


def _add_label(
    rng: np.random.Generator, kind: str, colour: str, size: float, density: float, spec: SceneSpec
) -> tuple[np.ndarray, np.ndarray, _LabelPatch]:
    """Surfels of a label patch for one object, and the patch (its half-angle drawn per object)."""
    label = label_colours(colour)[rng.integers(len(COLOURS) - 1)]
    part = label_part(kind, size, spec.label_size)
    pts, nrm = sample_part(rng, part, density)
    patch = _LabelPatch(label, np.asarray(part.translation), float(rng.uniform(35.0, 55.0)))
    return pts, nrm, patch


def object_crops(
    rng: np.random.Generator,
    n_objects: int,
    views_per_object: int = 4,
    *,
    density: float = 15000.0,
    side_range: tuple[int, int] = (24, 80),
    min_area: int = 30,
    label_share: float = 0.0,
    stripe_share: float = 0.0,
) -> list[LabelledCrop]:
    """Crops of single objects (uniform over colour x kind) from random viewpoints and scales.

    label_share: the share of objects of a labellable kind that carry a label; half of their views
    look at the label's side, and views where the label is half-read are left out.
    stripe_share: the share of objects striped as the capture suite's are (the label stays flat).
    Both 0 keep the random stream (and so the crops) of before labels and stripes existed.
    """
    spec = SceneSpec(sh_degree=1 if label_share > 0 else 0)
    out: list[LabelledCrop] = []
    colours, kinds = list(COLOURS), list(KINDS)
    fov = 40.0
    for _ in range(n_objects):
        colour, kind = colours[rng.integers(len(colours))], kinds[rng.integers(len(kinds))]
        pts, nrm, rgb = [], [], []
        size = float(rng.uniform(*spec.size_range))
        for part in KINDS[kind](size):
            p, n = sample_part(rng, part, density)
            pts.append(p)
            nrm.append(n)
            rgb.append(
                np.broadcast_to(COLOURS[colour] if part.colour == "main" else NEUTRALS[part.colour], p.shape)
            )
        if stripe_share > 0 and rng.uniform() < stripe_share:
            on = stripes(np.concatenate(pts), spec.texture_period, rng)
            rgb = [np.concatenate(rgb) * np.where(on, 1.0 - spec.texture_contrast, 1.0)[:, None]]
        patch = None
        if label_share > 0 and kind in LABELLED_KINDS and rng.uniform() < label_share:
            p, n, patch = _add_label(rng, kind, colour, size, density, spec)
            pts.append(p)
            nrm.append(n)
            rgb.append(np.broadcast_to(COLOURS[colour], p.shape))
        points = np.concatenate(pts)
        normals = np.concatenate(nrm)
        sigma = np.full(len(points), spec.tangential_scale / np.sqrt(density))
        g = surfels_to_gaussians(points, normals, np.concatenate(rgb), sigma, spec, rng)
        if patch is not None:
            rows = np.arange(len(points) - len(pts[-1]), len(points))
            paint_label(
                g, rows, normals[rows], patch.colour, np.array([0.0, 1.0, 0.0]), patch.half_angle_deg, spec
            )
        renderer = GaussianRenderer(g)
        centre = (points.min(0) + points.max(0)) / 2
        radius = float(np.linalg.norm(points - centre, axis=1).max())
        for _ in range(views_per_object):
            side = int(rng.integers(*side_range))
            fill = rng.uniform(0.45, 0.95)
            distance = radius / np.tan(np.deg2rad(fov) / 2) / fill
            azimuth, elevation = None, (5.0, 70.0)
            if patch is not None and rng.uniform() < 0.5:  # towards the label's side (+y), low
                azimuth, elevation = np.pi / 2 + rng.normal(0.0, 0.3), (5.0, 35.0)
            eye = _random_eye(rng, centre, distance, elevation, azimuth)
            label = patch.seen_from(eye) if patch is not None else None
            w2c = look_at(eye, centre + rng.normal(0, 0.1 * radius, 3))
            res = renderer.render(pinhole(side, side, fov), w2c, side, side, background=(0.5, 0.5, 0.5))
            labels = np.where(res.alpha > 0.5, 0, -1).astype(np.int32)
            if label is not False and (labels == 0).sum() >= min_area:
                assert res.rgb is not None  # a colour render
                out.append(LabelledCrop(mask_crops(to_uint8(res.rgb), labels)[0], colour, kind, label))
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
    textured_share: float = 0.0,
) -> list[LabelledCrop]:
    """Object and background crops from random views of random scenes, masks from id images.

    textured_share: the share of scenes with the capture suite's texture (striped objects, a
    checkered room); 0 keeps the random stream of before.
    """
    out: list[LabelledCrop] = []
    for _ in range(n_scenes):
        textured = textured_share > 0 and rng.uniform() < textured_share
        spec = SceneSpec(
            texture="stripes" if textured else "flat",
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
            colour_render = renderer.render(K, w2c, width, height, background=spec.background).rgb
            assert colour_render is not None
            rgb = to_uint8(colour_render)
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
