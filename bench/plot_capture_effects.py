"""Evidence that the capture suite has the effects the paper's Fig. 2-3 describe (issue #14, item 2).

The tiny CLIP's cosine between a masked crop of an object (GT mask from the id images, so the
segmenter's errors do not blur the picture) and the task that names it is plotted
- against the viewing angle from a label's facing direction, for the labelled objects and the
  tasks that name their label (paper Fig. 3a: the "Expo" marker scores high only label-on);
- against the object's share of the frame, from close-ups that overfill it to far views where it
  spans a few pixels (paper Fig. 3b: too near or too far gives outlier scores);
and the histogram of cosines of relevant vs irrelevant (mask, task) pairs over the scenes' own
walk frames (paper Fig. 2). Writes three PNGs (drawn with PIL: the project has no plotting
library) and prints binned medians.

Usage: ``.venv/bin/python bench/plot_capture_effects.py [--scenes 3] [--out docs] [--profile YAML]``
(a few minutes on 2 CPU cores: it renders about 1000 views at 320x240).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from scipy import ndimage

from bayesian_fields_core.eval.synthetic.builder import build_scene
from bayesian_fields_core.eval.synthetic.cameras import capture_frames
from bayesian_fields_core.eval.synthetic.generate import to_uint8
from bayesian_fields_core.eval.synthetic.id_images import IdImageRenderer
from bayesian_fields_core.eval.synthetic.pieces import SyntheticScene
from bayesian_fields_core.eval.synthetic.spec import suite_specs
from bayesian_fields_core.eval.synthetic.tasks import fine_task_text, label_task_text, make_tasks
from bayesian_fields_core.geometry.transforms import look_at, pinhole
from bayesian_fields_core.perception.crops import mask_crops
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.render import GaussianRenderer

MIN_PIXELS = 30


# ---------------------------------------------------------------------------------------------
# A minimal chart on PIL: axes with ticks, scatter points, lines, step histograms, a legend.


@dataclass
class Chart:
    """A 2-D chart on a PIL image; x may be logarithmic. Call `save` after drawing."""

    title: str
    xlabel: str
    ylabel: str
    xlim: tuple[float, float]
    ylim: tuple[float, float]
    log_x: bool = False
    size: tuple[int, int] = (720, 460)
    margin: tuple[int, int, int, int] = (70, 40, 30, 60)  # left, top, right, bottom
    legend: list[tuple[str, tuple[int, int, int]]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.image = Image.new("RGB", self.size, "white")
        self.draw = ImageDraw.Draw(self.image)

    def _fx(self, x: np.ndarray) -> np.ndarray:
        lo, hi = self.xlim
        if self.log_x:
            x, lo, hi = np.log10(x), np.log10(lo), np.log10(hi)
        left, _, right, _ = self.margin
        return left + (np.asarray(x) - lo) / (hi - lo) * (self.size[0] - left - right)

    def _fy(self, y: np.ndarray) -> np.ndarray:
        lo, hi = self.ylim
        _, top, _, bottom = self.margin
        return self.size[1] - bottom - (np.asarray(y) - lo) / (hi - lo) * (self.size[1] - top - bottom)

    def axes(self, xticks: Sequence[float], yticks: Sequence[float]) -> None:
        left, top, right, bottom = self.margin
        w, h = self.size
        self.draw.rectangle([left, top, w - right, h - bottom], outline="black")
        for x in xticks:
            px = float(self._fx(np.array(x)))
            self.draw.line([px, h - bottom, px, h - bottom + 5], fill="black")
            self.draw.line([px, top, px, h - bottom], fill=(225, 225, 225))
            self.draw.text((px - 12, h - bottom + 8), f"{x:g}", fill="black")
        for y in yticks:
            py = float(self._fy(np.array(y)))
            self.draw.line([left - 5, py, left, py], fill="black")
            self.draw.line([left, py, w - right, py], fill=(225, 225, 225))
            self.draw.text((left - 40, py - 6), f"{y:.2f}", fill="black")
        self.draw.text((left, 12), self.title, fill="black")
        self.draw.text((w / 2 - 4 * len(self.xlabel), h - 24), self.xlabel, fill="black")
        self.draw.text((6, top - 22), self.ylabel, fill="black")

    def points(self, x: np.ndarray, y: np.ndarray, colour: tuple[int, int, int], r: float = 2.5) -> None:
        for px, py in zip(self._fx(x), self._fy(y), strict=True):
            self.draw.ellipse([px - r, py - r, px + r, py + r], fill=colour)

    def line(self, x: np.ndarray, y: np.ndarray, colour: tuple[int, int, int], width: int = 3) -> None:
        ok = np.isfinite(y)
        pts = list(zip(self._fx(x[ok]).tolist(), self._fy(y[ok]).tolist(), strict=True))
        if len(pts) > 1:
            self.draw.line(pts, fill=colour, width=width)

    def step_histogram(self, edges: np.ndarray, heights: np.ndarray, colour: tuple[int, int, int]) -> None:
        for lo, hi, hgt in zip(edges[:-1], edges[1:], heights, strict=True):
            x0, x1 = float(self._fx(np.array(lo))), float(self._fx(np.array(hi)))
            y0, y1 = float(self._fy(np.array(0.0))), float(self._fy(np.array(hgt)))
            self.draw.rectangle([x0, y1, x1, y0], outline=colour, width=2)

    def save(self, path: Path) -> None:
        left, top, right, _ = self.margin
        for i, (name, colour) in enumerate(self.legend):
            x, y = self.size[0] - right - 260, top + 8 + 16 * i
            self.draw.rectangle([x, y + 2, x + 10, y + 12], fill=colour)
            self.draw.text((x + 16, y), name, fill="black")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.image.save(path, optimize=True)


# ---------------------------------------------------------------------------------------------
# Measurements.


@dataclass
class Views:
    """One scene's renderers and the encoder, to crop and embed GT masks of arbitrary views."""

    scene: SyntheticScene
    encoder: object
    width: int = 320
    height: int = 240

    def __post_init__(self) -> None:
        self.rgb = GaussianRenderer(self.scene.gaussians)
        self.ids = IdImageRenderer(self.scene.gaussians, self.scene.instance_ids)
        self.K = pinhole(self.width, self.height, self.scene.spec.fov_deg)

    def crops(
        self, w2c: np.ndarray, K: np.ndarray | None = None
    ) -> tuple[list[int], list[np.ndarray], np.ndarray]:
        """Instances with >= MIN_PIXELS pixels in the view, their masked crops and pixel counts."""
        K = self.K if K is None else K
        image = to_uint8(self.rgb.render(K, w2c, self.width, self.height, background=(0.0, 0.0, 0.0)).rgb)
        id_image = self.ids.render(K, w2c, self.width, self.height)
        present, counts = np.unique(id_image[id_image >= 0], return_counts=True)
        keep = counts >= MIN_PIXELS
        present, counts = present[keep], counts[keep]
        labels = np.full(id_image.shape, -1, dtype=np.int32)
        for k, inst in enumerate(present):
            labels[_without_specks(id_image == inst)] = k
        return [int(i) for i in present], mask_crops(image, labels) if len(present) else [], counts

    def embed(self, crops: list[np.ndarray]) -> np.ndarray:
        e = np.asarray(self.encoder.encode_images(crops), dtype=np.float64)  # type: ignore[attr-defined]
        return e / np.linalg.norm(e, axis=1, keepdims=True)


def _without_specks(mask: np.ndarray) -> np.ndarray:
    """The mask without regions under a tenth of its largest: the id images decode a few stray
    pixels from colour mixtures at far boundaries, and one stray pixel stretches the crop's box
    (a mug head-on became a speck in a 236-pixel crop)."""
    regions, n = ndimage.label(mask)
    if n <= 1:
        return mask
    sizes = np.bincount(regions.ravel())[1:]
    return np.isin(regions, np.flatnonzero(sizes >= 0.1 * sizes.max()) + 1)


def _text(encoder: object, texts: list[str]) -> np.ndarray:
    e = np.asarray(encoder.encode_texts(texts), dtype=np.float64)  # type: ignore[attr-defined]
    return e / np.linalg.norm(e, axis=1, keepdims=True)


def angle_sweep(views: Views, step_deg: float = 15.0) -> list[tuple[float, float, float]]:
    """(angle from the label normal, cosine to the label task, cosine to the plain fine task) for
    views around each labelled object at 0.45 m, slightly above it."""
    out = []
    for label in views.scene.labels:
        inst = views.scene.instances[label.instance_id]
        assert inst.colour is not None
        texts = _text(
            views.encoder,
            [
                label_task_text(inst.colour, inst.kind, label.colour),
                fine_task_text(inst.colour, inst.kind, 1),
            ],
        )
        side = np.cross([0.0, 0.0, 1.0], label.normal)
        for deg in np.arange(0.0, 360.0, step_deg):
            a = np.deg2rad(deg)
            eye = inst.center + 0.45 * (np.cos(a) * label.normal + np.sin(a) * side) + [0.0, 0.0, 0.12]
            present, crops, _ = views.crops(look_at(eye, inst.center))
            if label.instance_id not in present:
                continue
            emb = views.embed([crops[present.index(label.instance_id)]])[0]
            angle = min(deg, 360.0 - deg)
            out.append((angle, float(emb @ texts[0]), float(emb @ texts[1])))
    return out


def distance_sweep(views: Views, rng: np.random.Generator) -> list[tuple[float, float]]:
    """(object's share of the frame, cosine to its fine task) from 0.12 to 4 m along a random ray
    per object (close-ups overfill the frame and are cut by its border)."""
    out = []
    objects = [i for i in views.scene.instances if i.category == "object"]
    texts = _text(views.encoder, [fine_task_text(o.colour or "", o.kind, 1) for o in objects])
    for obj, text in zip(objects, texts, strict=True):
        az, el = rng.uniform(0, 2 * np.pi), np.deg2rad(rng.uniform(20, 45))
        ray = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        for d in np.geomspace(0.12, 4.0, 14):
            eye = obj.center + d * ray
            half = views.scene.spec.room_size / 2 - 0.05
            if np.any(np.abs(eye[:2]) > half) or eye[2] > views.scene.spec.wall_height - 0.05:
                continue
            present, crops, counts = views.crops(look_at(eye, obj.center))
            if obj.id not in present:
                continue
            k = present.index(obj.id)
            share = counts[k] / (views.width * views.height)
            out.append((float(share), float(views.embed([crops[k]])[0] @ text)))
    return out


def walk_scores(views: Views) -> tuple[list[float], list[float]]:
    """Cosines of relevant and irrelevant (GT mask, task) pairs over the scene's walk frames."""
    spec = views.scene.spec
    tasks = make_tasks(spec, views.scene.instances, np.random.default_rng([spec.seed, 2]))
    texts = _text(views.encoder, [t.text for t in tasks])
    relevant, irrelevant = [], []
    for frame in capture_frames(spec, views.scene):
        present, crops, _ = views.crops(frame.world_to_camera, frame.K)
        if not present:
            continue
        cos = views.embed(crops) @ texts.T
        for i, inst in enumerate(present):
            for t, task in enumerate(tasks):
                (relevant if inst in task.instance_ids else irrelevant).append(float(cos[i, t]))
    return relevant, irrelevant


def _binned_median(x: np.ndarray, y: np.ndarray, edges: np.ndarray) -> np.ndarray:
    idx = np.digitize(x, edges) - 1
    return np.array([np.median(y[idx == b]) if np.any(idx == b) else np.nan for b in range(len(edges) - 1)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=int, default=3, help="first N capture-suite scenes")
    ap.add_argument("--out", default="docs", help="folder for the PNGs")
    ap.add_argument("--profile", default=None, help="model profile YAML (default: the bundled tiny CLIP)")
    args = ap.parse_args(argv)
    encoder = load_models(args.profile).encoder
    rng = np.random.default_rng(0)
    angles, shares, relevant, irrelevant = [], [], [], []
    for spec in suite_specs(suite="capture")[: args.scenes]:
        views = Views(build_scene(spec), encoder)
        angles += angle_sweep(views)
        shares += distance_sweep(views, rng)
        rel, irr = walk_scores(views)
        relevant += rel
        irrelevant += irr
        print(
            f"{spec.name}: {len(angles)} angle views, {len(shares)} distance views, {len(rel)} relevant pairs"
        )
    out = Path(args.out)
    blue, orange, grey = (31, 119, 180), (230, 120, 20), (150, 150, 150)

    a = np.array(angles)
    edges = np.array([0, 15, 30, 45, 60, 90, 120, 181])
    med_label, med_plain = _binned_median(a[:, 0], a[:, 1], edges), _binned_median(a[:, 0], a[:, 2], edges)
    lo = float(min(a[:, 1:].min(), 0.0)) - 0.02
    chart = Chart(
        "tiny CLIP cosine vs angle from the label's facing direction (labelled objects)",
        "angle from label normal (deg)",
        "cosine",
        (0, 180),
        (lo, float(a[:, 1:].max()) + 0.05),
        legend=[("task naming the label (median line)", blue), ("plain colour+kind task", orange)],
    )
    chart.axes([0, 30, 60, 90, 120, 150, 180], np.round(np.linspace(chart.ylim[0], chart.ylim[1], 6), 2))
    chart.points(a[:, 0], a[:, 2], (250, 190, 140))
    chart.points(a[:, 0], a[:, 1], (140, 180, 220))
    mids = (edges[:-1] + np.minimum(edges[1:], 180)) / 2
    chart.line(mids, med_plain, orange)
    chart.line(mids, med_label, blue)
    chart.save(out / "capture_cosine_vs_angle.png")
    print("angle bins (deg):", edges.tolist())
    print("  median cosine, label task:", np.round(med_label, 3).tolist())
    print("  median cosine, plain task:", np.round(med_plain, 3).tolist())

    s = np.array(shares)
    s_edges = np.array([1e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0001])
    med = _binned_median(s[:, 0], s[:, 1], s_edges)
    chart = Chart(
        "tiny CLIP cosine to the object's task vs its share of the frame",
        "object's share of the frame's pixels (log)",
        "cosine",
        (1e-4, 1.0),
        (float(s[:, 1].min()) - 0.02, float(s[:, 1].max()) + 0.05),
        log_x=True,
        legend=[("one view (GT mask crop)", grey), ("median per bin", blue)],
    )
    chart.axes([1e-4, 1e-3, 1e-2, 0.1, 1.0], np.round(np.linspace(chart.ylim[0], chart.ylim[1], 6), 2))
    chart.points(np.clip(s[:, 0], 1e-4, 1.0), s[:, 1], grey)
    chart.line(np.sqrt(s_edges[:-1] * s_edges[1:]), med, blue)
    chart.save(out / "capture_cosine_vs_share.png")
    print("share bins:", s_edges.tolist())
    print("  median cosine:", np.round(med, 3).tolist())

    rel, irr = np.array(relevant), np.array(irrelevant)
    h_edges = np.linspace(min(rel.min(), irr.min()), max(rel.max(), irr.max()), 31)
    h_rel = np.histogram(rel, h_edges, density=True)[0]
    h_irr = np.histogram(irr, h_edges, density=True)[0]
    chart = Chart(
        "cosine of relevant vs irrelevant (mask, task) pairs, capture walk frames (GT masks)",
        "cosine",
        "density",
        (float(h_edges[0]), float(h_edges[-1])),
        (0.0, float(max(h_rel.max(), h_irr.max())) * 1.1),
        legend=[(f"relevant ({rel.size} pairs)", blue), (f"irrelevant ({irr.size} pairs)", orange)],
    )
    chart.axes(
        np.round(np.linspace(h_edges[0], h_edges[-1], 6), 2),
        np.round(np.linspace(0, chart.ylim[1], 5), 1),
    )
    chart.step_histogram(h_edges, h_irr, orange)
    chart.step_histogram(h_edges, h_rel, blue)
    chart.save(out / "capture_score_histogram.png")
    q = [5, 25, 50, 75, 95]
    print("relevant cosine percentiles", q, np.round(np.percentile(rel, q), 3).tolist())
    print("irrelevant cosine percentiles", q, np.round(np.percentile(irr, q), 3).tolist())
    print(
        f"share of relevant below the irrelevant 95th percentile: {np.mean(rel < np.percentile(irr, 95)):.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
