"""What `bfields view` shows, computed without any GUI: the (capped) splat, its per-Gaussian object
ids and relevance, the colourings, and the object picked by a click ray.

Kept apart from the viser server so it is testable and so the viewer's start time is dominated by
reading the files, not by the GUI.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.obb import OrientedBox, minimum_obb
from bayesian_fields_core.job.artifacts import FUSION_KEY, RESULT_PREFIX
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results.colours import (
    BACKGROUND_GREY,
    DIM,
    TINT,
    base_colours,
    object_palette,
    rank_colour,
)
from bayesian_fields_core.results.format import Result
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.scene.types import Frame, Gaussians

DEFAULT_MAX_GAUSSIANS = 1_000_000
"""Cap on the Gaussians sent to the browser. Above it the viewer keeps every Gaussian of a selected
object and a uniform random sample of the rest (seed 0): WebGL sorting in the browser, not the
server, is what slows down past about a million splats on a laptop GPU."""


_HEAT = np.array(  # a perceptual dark-blue -> teal -> yellow ramp (viridis anchor colours)
    [[0.267, 0.005, 0.329], [0.230, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383],
     [0.993, 0.906, 0.144]],
    dtype=np.float32,
)  # fmt: skip


def heat_colours(values: np.ndarray) -> np.ndarray:
    """(N,) values in [0, 1] -> (N, 3) RGB on the heat ramp."""
    v = np.clip(np.asarray(values, dtype=np.float32), 0, 1) * (len(_HEAT) - 1)
    lo = np.floor(v).astype(np.int64).clip(0, len(_HEAT) - 2)
    frac = (v - lo)[:, None]
    return _HEAT[lo] * (1 - frac) + _HEAT[lo + 1] * frac


@dataclass
class ViewData:
    """A result and its scene, ready to show.

    gaussians: the shown (M,) Gaussians, M <= max_gaussians; `kept` (M,) their indices in the splat.
    object_ids: (M,) object of each shown Gaussian, -1 none.
    gaussian_relevance: (M, T) per-Gaussian p(relevant) per task: the fused probabilities when the
        run folder has them, else each object's relevance broadcast to its Gaussians (0 outside).
    frames: the input cameras ([] when the scene folder is not available).
    """

    result: Result
    summary: dict[str, Any]
    gaussians: Gaussians
    kept: np.ndarray
    object_ids: np.ndarray
    gaussian_relevance: np.ndarray
    frames: list[Frame]
    total_gaussians: int
    relevance_source: str
    base: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.base = base_colours(self.gaussians)

    @property
    def tasks(self) -> list[str]:
        return list(self.result.tasks)

    @property
    def unit(self) -> float:
        """The scene's length unit for display: the run's scene scale (format 1.4), else, for an
        older result, the median distance of the shown Gaussian centres from their median (the
        same order of size, and it follows the scene's units alike); 1.0 for a degenerate set."""
        value = (self.result.scene_scale or {}).get("value")
        if value is not None and np.isfinite(value) and float(value) > 0:
            return float(value)
        means = np.asarray(self.gaussians.means, dtype=np.float64)
        if len(means) == 0:
            return 1.0
        spread = float(np.median(np.linalg.norm(means - np.median(means, axis=0), axis=1)))
        return spread if np.isfinite(spread) and spread > 0 else 1.0

    def task_colours(self, task: str) -> np.ndarray:
        """(M, 3): the task's objects tinted by rank, every other Gaussian dimmed."""
        rgb = self.base * DIM
        for rank, obj in enumerate(self.result.selections.get(task, [])):
            mask = self.object_ids == obj.object_id
            rgb[mask] = (1 - TINT) * self.base[mask] + TINT * rank_colour(rank)
        return rgb

    def heat(self, task: str) -> np.ndarray:
        return heat_colours(self.gaussian_relevance[:, self.tasks.index(task)])

    def object_colours(self) -> np.ndarray:
        """(M, 3): each object in its palette colour (as in scene_objects.ply), the rest grey."""
        rgb = np.full((len(self.object_ids), 3), BACKGROUND_GREY, dtype=np.float32)
        inside = self.object_ids >= 0
        rgb[inside] = object_palette(self.result.num_objects)[self.object_ids[inside]]
        return rgb

    def object_info(self, object_id: int) -> dict[str, Any]:
        """Every task's p(relevant) and conditional for one object, its Gaussian count and box."""
        scores = self.result.task_scores[object_id]
        cond = np.asarray(self.result.probabilities)[object_id]
        box: OrientedBox | None = None
        for objs in self.result.selections.values():
            box = next((o.box for o in objs if o.object_id == object_id), box)
        ids = np.asarray(self.result.object_ids)
        if box is None:
            points = np.asarray(self.gaussians.means)[self.object_ids == object_id]
            box = minimum_obb(points) if len(points) >= 4 else None
        return {
            "object_id": object_id,
            "num_gaussians": int(np.count_nonzero(ids == object_id)),
            "tasks": {
                t: {"relevance": float(scores[i]), "conditional": float(cond[i])}
                for i, t in enumerate(self.tasks)
            },
            "null": float(cond[-1]),
            "box": box.to_dict() if box is not None else None,
        }

    def pick(self, origin: np.ndarray, direction: np.ndarray, *, radius: float | None = None) -> int | None:
        """The object whose Gaussian centre lies nearest the ray (within `radius`, default 1% of the
        scene's diagonal), the closest along the ray among near ties; None if no object is hit."""
        inside = self.object_ids >= 0
        if not inside.any():
            return None
        pts = np.asarray(self.gaussians.means, dtype=np.float64)[inside]
        d = np.asarray(direction, dtype=np.float64)
        d = d / max(float(np.linalg.norm(d)), 1e-12)
        rel = pts - np.asarray(origin, dtype=np.float64)
        t = rel @ d
        perp = np.linalg.norm(rel - t[:, None] * d, axis=1)
        if radius is None:
            span = np.asarray(self.gaussians.means).max(0) - np.asarray(self.gaussians.means).min(0)
            radius = 0.01 * float(np.linalg.norm(span))
        ok = (t > 0) & (perp <= radius)
        if not ok.any():
            return None
        candidates = np.flatnonzero(ok)
        return int(self.object_ids[inside][candidates[np.argmin(t[candidates])]])


def result_root(path: Path) -> tuple[Path, str]:
    """(run folder, result prefix) for a run folder (holding result/) or the result folder itself."""
    path = Path(path)
    if (path / "result" / "summary.json").is_file():
        return path, RESULT_PREFIX
    if (path / "summary.json").is_file():
        return path, ""
    raise InputError("no result here (expected summary.json or result/summary.json)", source=str(path))


def subsample(object_ids: np.ndarray, keep_always: np.ndarray, cap: int) -> np.ndarray:
    """Sorted indices of at most `cap` Gaussians: all of `keep_always` (bool mask) first, then a
    seeded uniform sample of the rest."""
    n = len(object_ids)
    if n <= cap:
        return np.arange(n)
    must = np.flatnonzero(keep_always)[:cap]
    rest = np.flatnonzero(~keep_always)
    extra = np.random.default_rng(0).choice(rest, size=min(len(rest), cap - len(must)), replace=False)
    return np.sort(np.concatenate([must, extra]))


def load_view(
    path: Path, *, scene_dir: Path | None = None, max_gaussians: int = DEFAULT_MAX_GAUSSIANS
) -> ViewData:
    """Read a result and its scene. The scene is `scene_dir`, else the folder summary.json records
    (`scene.folder`), else the geometry of the result's own recoloured scene export (no cameras)."""
    from bayesian_fields_core.scene.loader import load_scene
    from bayesian_fields_core.scene.ply import read_ply

    root, prefix = result_root(path)
    store = LocalStore(root)
    result = read_result(store, prefix)
    summary = json.loads((root / prefix / "summary.json").read_text(encoding="utf-8"))
    recorded = (summary.get("scene") or {}).get("folder")
    folder = scene_dir or (Path(recorded) if recorded and Path(recorded).is_dir() else None)
    frames: list[Frame] = []
    if folder is not None:
        scene = load_scene(folder)
        gaussians, frames = scene.gaussians, scene.frames
    else:
        export = (summary.get("exports") or {}).get("scene")
        if not export or not (root / prefix / export).is_file():
            raise InputError(
                "the result records no local scene folder and has no scene export; pass --scene DIR",
                source=str(path),
            )
        gaussians = read_ply(root / prefix / export)
    if len(gaussians) != result.num_gaussians:
        raise InputError(
            f"the scene's splat has {len(gaussians)} Gaussians but the result has {result.num_gaussians}",
            source=str(folder or path),
        )
    ids = np.asarray(result.object_ids)
    selected = np.isin(ids, [o.object_id for objs in result.selections.values() for o in objs])
    kept = subsample(ids, selected, max_gaussians)
    relevance, source = _gaussian_relevance(root, prefix, result)
    return ViewData(
        result=result,
        summary=summary,
        gaussians=gaussians.subset(kept) if len(kept) < len(gaussians) else gaussians,
        kept=kept,
        object_ids=ids[kept],
        gaussian_relevance=relevance[kept],
        frames=frames,
        total_gaussians=len(gaussians),
        relevance_source=source,
    )


def _gaussian_relevance(root: Path, prefix: str, result: Result) -> tuple[np.ndarray, str]:
    """(N, T) per-Gaussian relevance and where it came from."""
    fused = root / FUSION_KEY
    if prefix == RESULT_PREFIX and fused.is_file():
        with np.load(fused, allow_pickle=False) as data:
            probs = np.asarray(data["probabilities"], dtype=np.float32)
        if probs.shape == (result.num_gaussians, len(result.tasks)):
            return probs, "fused per-Gaussian probabilities"
    ids = np.asarray(result.object_ids)
    table = np.vstack([result.task_scores, np.zeros((1, len(result.tasks)))]).astype(np.float32)
    return table[np.where(ids >= 0, ids, len(table) - 1)], "object relevance per Gaussian"
