"""Per-task preview images of a result and a contact sheet of all tasks.

A preview is what a person looks at first: the scene rendered with the project's renderer from the
input view that sees the task's top object best, the task's selected objects tinted in their rank
colour and outlined, everything else dimmed, and a legend strip (task, rank, object id, p).

Each preview costs one render of one view at reduced resolution (`preview_max_side`) with six
channels: the tinted colours, and label colours (each selected object a flat palette colour, the
rest opaque black) whose per-pixel nearest palette colour gives the object masks that are outlined. Occlusion is thus
the renderer's own. The best view is chosen without rendering: the frame in which most of the top
object's Gaussian centres project inside the image (in front of the camera), ties broken by the
larger projected footprint.
"""

from __future__ import annotations

import io
import math
import textwrap
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from bayesian_fields_core.compute.threads import torch_threads
from bayesian_fields_core.render.output import RasterSettings
from bayesian_fields_core.results.colours import DIM, TINT, base_colours, rank_colour
from bayesian_fields_core.results.format import Result
from bayesian_fields_core.scene.types import Frame, Gaussians

PREVIEW_DIR = "previews/"
CONTACT_SHEET_KEY = "previews/contact_sheet.png"
_MAX_VIEW_POINTS = 4000

PREVIEW_RASTER = RasterSettings(tile_size=8, cull_faint_tiles=True)
"""Rasterisation constants of previews: the renderer's defaults with 8-pixel tiles.

At preview resolution most Gaussians' footprints span a few pixels, so on 16-pixel tiles most of
the (tile pixel, Gaussian) pairs the compositing evaluates are zero; 8-pixel tiles halve the CPU
time of a preview at 400 k Gaussians (bench/bench_previews.py). Per pixel the blending rules are
the renderer's own; the only change is that a Gaussian's tail beyond its 3-sigma box, which a
16-pixel tile sometimes still covered, is dropped more often (under one 8-bit level on the
scale bench's previews)."""

PREVIEW_THREADS = 1
"""torch intra-op threads while rendering previews (None: leave torch's setting alone).

A preview's compositing runs a few hundred small steps; with several intra-op threads each step
ends in a barrier where idle threads spin, so on the scale bench two threads cost about twice the
CPU of one for a little less wall time, and on a busy machine far more (a spinning thread waits
for one that is descheduled). The cluster stage runs on the CPU queue, where CPU is the cost."""


def preview_key(task_index: int) -> str:
    return f"{PREVIEW_DIR}task_{task_index:02d}.png"


@dataclass
class Preview:
    """One task's preview: the PNG bytes and what is listed in summary.json."""

    task: str
    key: str
    frame: str | None
    png: bytes
    width: int
    height: int

    def entry(self) -> dict[str, Any]:
        return {"task": self.task, "file": self.key, "frame": self.frame, "width": self.width,
                "height": self.height}  # fmt: skip


def best_view(frames: list[Frame], points: np.ndarray) -> int:
    """Index of the frame that sees `points` (M, 3) best: most centres in front of the camera and
    inside the image; ties go to the larger projected bounding box (a closer view)."""
    if len(points) > _MAX_VIEW_POINTS:
        points = points[np.linspace(0, len(points) - 1, _MAX_VIEW_POINTS).astype(np.int64)]
    best, best_score = 0, (-1, -1.0)
    homo = np.concatenate([points, np.ones((len(points), 1))], axis=1).T  # (4, M)
    for i, frame in enumerate(frames):
        cam = (frame.world_to_camera @ homo)[:3]
        front = cam[2] > 0  # no absolute near plane: the scene's units are arbitrary
        if not front.any():
            continue
        uv = (frame.K @ cam[:, front])[:2] / cam[2, front]
        inside = (uv[0] >= 0) & (uv[0] < frame.width) & (uv[1] >= 0) & (uv[1] < frame.height)
        count = int(inside.sum())
        area = 0.0
        if count:
            span = uv[:, inside].max(axis=1) - uv[:, inside].min(axis=1)
            area = float(span[0] * span[1]) / float(frame.width * frame.height)
        if (count, area) > best_score:
            best, best_score = i, (count, area)
    return best


def _scaled_camera(frame: Frame, max_side: int) -> tuple[np.ndarray, int, int]:
    scale = min(1.0, max_side / max(frame.width, frame.height))
    K = np.array(frame.K, dtype=np.float64)
    K[:2] *= scale
    return K, max(1, round(frame.width * scale)), max(1, round(frame.height * scale))


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only the bitmap font
        return ImageFont.load_default()


def _outline(labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of a labelled region (label >= 0) whose 4-neighbour differs."""
    edge = np.zeros(labels.shape, dtype=bool)
    inside = labels >= 0
    for axis in (0, 1):
        diff = np.diff(labels, axis=axis) != 0
        pad = [(0, 0), (0, 0)]
        pad[axis] = (1, 0)
        edge |= np.pad(diff, pad) & inside
        pad[axis] = (0, 1)
        edge |= np.pad(diff, pad) & inside
    return edge


def _legend(
    image: Image.Image, task: str, rows: list[tuple[int, int, float]], empty: str = "no object selected"
) -> Image.Image:
    """The image with a legend strip below: the task, then one line per (rank, object, p), or
    `empty` (why nothing is shown, wrapped to the strip's width) when the task has no object."""
    width = max(image.width, 320)
    line = 16
    font, title_font = _font(12), _font(14)
    sample = "best object 37 scored 0.632, below the not-found threshold"
    chars = max(int((width - 16) * len(sample) / max(font.getlength(sample), 1)), 20)
    empty_lines = textwrap.wrap(empty, chars) or [""]
    lines = len(rows) if rows else len(empty_lines)
    strip = 8 + 18 + line * lines + 6
    out = Image.new("RGB", (width, image.height + strip), (24, 24, 28))
    out.paste(image, ((width - image.width) // 2, 0))
    draw = ImageDraw.Draw(out)
    y = image.height + 6
    draw.text((8, y), task, fill=(240, 240, 240), font=title_font)
    y += 20
    if not rows:
        draw.text((8, y), "\n".join(empty_lines), fill=(180, 180, 180), font=font, spacing=line - 12)
    for rank, object_id, p in rows:
        colour = tuple(int(c * 255) for c in rank_colour(rank))
        draw.rectangle((8, y + 2, 20, y + 13), fill=colour)
        draw.text((26, y), f"#{rank + 1}  object {object_id}   p = {p:.3f}", fill=(230, 230, 230), font=font)
        y += line
    return out


def _png(image: Image.Image) -> bytes:
    buf = io.BytesIO()
    image.save(buf, format="PNG", optimize=False, compress_level=6)
    return buf.getvalue()


def _composite_colours(
    renderer: Any, K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int, colours: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """((H, W, C) alpha-blended per-Gaussian `colours` (N, C), (H, W) alpha) of one view, with the
    renderer's own projection, tiling and compositing: any number of view-independent channels
    in one pass (a preview's tinted colours and its label colours together)."""
    import torch

    from bayesian_fields_core.render.composite import composite
    from bayesian_fields_core.render.projection import project
    from bayesian_fields_core.render.tiles import bin_gaussians, faint_cull

    s = renderer.settings
    device = renderer.device
    with torch.no_grad():
        K_t = torch.as_tensor(np.asarray(K, dtype=np.float64), device=device)
        w2c_t = torch.as_tensor(np.asarray(world_to_camera, dtype=np.float64), device=device)
        proj = project(renderer.means, renderer.cov3d, renderer.opacities, K_t, w2c_t, width, height, s)
        features = torch.as_tensor(np.ascontiguousarray(colours, dtype=np.float32), device=device)[proj.ids]
        tiles_x = (width + s.tile_size - 1) // s.tile_size
        tiles_y = (height + s.tile_size - 1) // s.tile_size
        bins = bin_gaussians(proj.rect, proj.depth, tiles_x, tiles_x * tiles_y, faint_cull(proj, s))
        out = composite(
            proj.xy, proj.conic, proj.opacity, proj.depth, features, bins, tiles_x, tiles_y, s, median=False
        )
        image = out.features[:height, :width].clamp(0.0, 1.0)
        alpha = 1.0 - out.transmittance[:height, :width]
    return image.cpu().numpy(), alpha.cpu().numpy()


def render_previews(
    result: Result,
    gaussians: Gaussians,
    frames: list[Frame],
    *,
    max_side: int,
    device: str = "cpu",
    settings: RasterSettings = PREVIEW_RASTER,
    threads: int | None = PREVIEW_THREADS,
    near_plane: float | None = None,
) -> list[Preview]:
    """One preview per task of `result` (in task order), rendered from the scene's frames.

    One renderer serves every task, and each task's view is composited once, with six channels:
    the tinted colours and the flat label colours (two renders per task before; at 400 k
    Gaussians each CPU render of a preview takes seconds). `settings` are the rasterisation
    constants (`PREVIEW_RASTER` by default); torch runs with `threads` intra-op threads meanwhile
    (its previous setting is restored). `near_plane` (scene units) overrides the settings' one:
    the run's `SceneLengths.render_near`, so a scene in small units is not culled away."""
    if not frames:
        return []
    with torch_threads(threads):
        from bayesian_fields_core.render.renderer import GaussianRenderer

        ids = np.asarray(result.object_ids)
        base = base_colours(gaussians)
        renderer = GaussianRenderer(
            gaussians, device=device, backend="torch", settings=settings, near_plane=near_plane
        )
        background = np.array([0.08, 0.08, 0.1], dtype=np.float32)
        previews = []
        for t, task in enumerate(result.tasks):
            objects = result.selections.get(task, [])
            top = ids == objects[0].object_id if objects else np.ones(len(ids), dtype=bool)
            index = best_view(frames, np.asarray(gaussians.means)[top]) if top.any() else 0
            frame = frames[index]
            K, width, height = _scaled_camera(frame, max_side)
            tinted = base * DIM
            flat = np.zeros_like(base)
            for rank, obj in enumerate(objects):
                mask = ids == obj.object_id
                colour = rank_colour(rank)
                tinted[mask] = (1 - TINT) * base[mask] + TINT * colour
                flat[mask] = colour
            image, alpha = _composite_colours(
                renderer, K, frame.world_to_camera, width, height, np.concatenate([tinted, flat], axis=1)
            )
            colour_img = np.clip(image[..., :3] + (1.0 - alpha)[..., None] * background, 0.0, 1.0)
            rgb = (colour_img * 255).astype(np.uint8)
            if objects:
                palette = np.array([rank_colour(r) for r in range(len(objects))])  # (k, 3)
                dist = ((image[:, :, None, 3:] - palette[None, None]) ** 2).sum(-1)  # (H, W, k)
                labels = np.where(dist.min(-1) < 0.12, dist.argmin(-1), -1)
                edge = _outline(labels)
                rgb[edge] = (palette[labels[edge]] * 255).astype(np.uint8)
                rgb[edge & (labels >= 0)] = np.maximum(rgb[edge & (labels >= 0)], 60)
            rows = [(r, o.object_id, o.probability) for r, o in enumerate(objects)]
            missing = result.not_found.get(task)
            image_out = _legend(
                Image.fromarray(rgb),
                task,
                rows,
                f"not found: {missing.reason}" if missing else "no object selected",
            )
            previews.append(
                Preview(
                    task=task,
                    key=preview_key(t),
                    frame=frame.name,
                    png=_png(image_out),
                    width=image_out.width,
                    height=image_out.height,
                )  # fmt: skip
            )
        return previews


def contact_sheet(previews: list[Preview], *, thumb_width: int = 320) -> bytes:
    """PNG of every task's preview in a grid (about square), each scaled to `thumb_width`."""
    images = [Image.open(io.BytesIO(p.png)).convert("RGB") for p in previews]
    thumbs = [im.resize((thumb_width, max(1, round(im.height * thumb_width / im.width)))) for im in images]
    cols = max(1, math.ceil(math.sqrt(len(thumbs))))
    rows = max(1, math.ceil(len(thumbs) / cols))
    cell_h = max((t.height for t in thumbs), default=1)
    gap = 4
    sheet = Image.new("RGB", (cols * (thumb_width + gap) + gap, rows * (cell_h + gap) + gap), (10, 10, 12))
    for i, thumb in enumerate(thumbs):
        r, c = divmod(i, cols)
        sheet.paste(thumb, (gap + c * (thumb_width + gap), gap + r * (cell_h + gap)))
    return _png(sheet)
