"""Build the Gaussians of a synthetic scene and their ground-truth instances (pure numpy).

The scene is a room (floor, walls), a table (top and legs) and objects from the vocabulary,
placed in separate groups on the table top. Every Gaussian belongs to exactly one instance, and
every instance gets an oriented box in its own frame (yaw only), so the boxes are tight and
contain all of their Gaussians' centres by construction.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bayesian_fields_core.eval.synthetic import capture
from bayesian_fields_core.eval.synthetic.pieces import Instance, Label, Piece, SyntheticScene, yaw_rotation
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.vocabulary import COLOURS, KINDS, NEUTRALS, Part, object_name, sample_part
from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.scene.types import Gaussians, sh_coefficient_count


def _tangent_frames(normals: np.ndarray) -> np.ndarray:
    """(n, 3, 3) right-handed rotations whose third column is the unit normal."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n], axis=2)


def lambert(normals: np.ndarray, spec: SceneSpec) -> np.ndarray:
    """Baked diffuse shading factor per surfel: ambient + (1 - ambient) * max(0, n . light).

    Trained splats bake the capture's lighting into their colours; without it every face of a
    cube has one flat colour and shapes are told apart by their silhouettes only.
    """
    light = np.asarray(spec.light_direction, dtype=np.float64)
    light = light / np.linalg.norm(light)
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    return spec.ambient + (1.0 - spec.ambient) * np.clip(unit @ light, 0.0, None)


def surfels_to_gaussians(
    points: np.ndarray,
    normals: np.ndarray,
    rgb: np.ndarray,
    sigma: np.ndarray,
    spec: SceneSpec,
    rng: np.random.Generator,
) -> Gaussians:
    """Flat Gaussians on a surface: in-plane std sigma, thickness sigma * flatness, normal-aligned.

    sigma is per point (different surfaces have different densities); scales get a little
    log-normal jitter, colours baked diffuse shading and a little noise, as a trained splat would.
    """
    n = points.shape[0]
    jitter = np.exp(rng.normal(0.0, 0.1, (n, 1)))
    scales = sigma[:, None] * jitter * np.array([[1.0, 1.0, spec.flatness]])
    quats = Rotation.from_matrix(_tangent_frames(normals)).as_quat(scalar_first=True)
    colour = np.clip(
        rgb * lambert(normals, spec)[:, None] + rng.normal(0.0, spec.colour_noise, (n, 3)), 0.0, 1.0
    )
    sh = np.zeros((n, sh_coefficient_count(spec.sh_degree), 3), dtype=np.float32)
    sh[:, 0, :] = (colour - 0.5) / SH_C0
    logit = np.log(spec.opacity / (1.0 - spec.opacity))
    return Gaussians(
        means=points.astype(np.float32),
        log_scales=np.log(scales).astype(np.float32),
        quats=quats.astype(np.float32),
        opacity_logits=np.full(n, logit, dtype=np.float32),
        sh=sh,
    )


def paint_label(
    gaussians: Gaussians,
    rows: np.ndarray,
    surface_normals: np.ndarray,
    colour: str,
    normal: np.ndarray,
    half_angle_deg: float,
    spec: SceneSpec,
) -> None:
    """Give the label Gaussians `rows` (R,) view-dependent colour in place: `colour`, shaded as
    their surface (`surface_normals` (R, 3)), within `half_angle_deg` of the label's `normal`,
    their current (object) colour beyond it (`capture.label_sh`). One place for scenes and for
    the tiny CLIP's single-object crops, so both show the same label."""
    label_rgb = np.asarray(COLOURS[colour]) * lambert(surface_normals, spec)[:, None]
    object_rgb = gaussians.sh[rows, 0, :].astype(np.float64) * SH_C0 + 0.5
    f_dc, f_rest = capture.label_sh(object_rgb, label_rgb, normal, half_angle_deg)
    gaussians.sh[rows, 0, :] = f_dc
    gaussians.sh[rows, 1:4, :] = f_rest


def _sample_parts(
    rng: np.random.Generator, parts: list[Part], density: float, main_rgb: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pts, nrm, rgb = [], [], []
    for part in parts:
        p, n = sample_part(rng, part, density)
        colour = main_rgb if part.colour == "main" else NEUTRALS[part.colour]
        pts.append(p)
        nrm.append(n)
        rgb.append(np.broadcast_to(np.asarray(colour), p.shape))
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(rgb)


def _room_pieces(spec: SceneSpec, rng: np.random.Generator) -> list[Piece]:
    """Floor, four walls and a table (top + legs) as background instances."""
    half = spec.room_size / 2
    pieces: list[Piece] = []
    floor = Part("rect", {"hx": half, "hy": half}, colour="floor")
    p, n, c = _sample_parts(rng, [floor], spec.room_density, NEUTRALS["floor"])
    pieces.append(Piece("floor", "floor", None, "background", p, n, c, spec.room_density, np.eye(3)))
    for angle in np.arange(4) * np.pi / 2:
        d = np.array([np.cos(angle), np.sin(angle), 0.0])
        t = np.array([np.sin(angle), -np.cos(angle), 0.0])
        rot = np.stack([t, [0.0, 0.0, 1.0], -d], axis=1)
        wall = Part(
            "rect",
            {"hx": half, "hy": spec.wall_height / 2},
            rotation=tuple(map(tuple, rot)),
            translation=tuple(d * half + np.array([0.0, 0.0, spec.wall_height / 2])),
            colour="wall",
        )
        p, n, c = _sample_parts(rng, [wall], spec.room_density, NEUTRALS["wall"])
        pieces.append(Piece("wall", "wall", None, "background", p, n, c, spec.room_density, np.eye(3)))
    hx, hy = spec.table_size[0] / 2, spec.table_size[1] / 2
    thick, leg = 0.02, 0.025
    parts = [
        Part(
            "box",
            {"hx": hx, "hy": hy, "hz": thick},
            translation=(0.0, 0.0, spec.table_height - thick),
            colour="wood",
        )
    ]
    leg_h = (spec.table_height - 2 * thick) / 2
    for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        centre = (sx * (hx - 0.06), sy * (hy - 0.06), leg_h)
        parts.append(Part("box", {"hx": leg, "hy": leg, "hz": leg_h}, translation=centre, colour="wood"))
    p, n, c = _sample_parts(rng, parts, spec.table_density, NEUTRALS["wood"])
    pieces.append(Piece("table", "table", None, "background", p, n, c, spec.table_density, np.eye(3)))
    return pieces


def choose_objects(spec: SceneSpec, rng: np.random.Generator) -> list[tuple[str, str]]:
    """(colour, kind) per object: distinct pairs from a colour subset, plus exact duplicates.

    Drawing from only n_colours colours makes colours repeat across kinds (coarse tasks such as
    "move all the red things") and leaves the other colours free for absent-object tasks.
    """
    colours = [str(c) for c in rng.permutation(list(COLOURS))[: spec.n_colours]]
    pairs = [(c, k) for c in colours for k in spec.kinds]
    order = rng.permutation(len(pairs))[: spec.n_objects - spec.n_duplicates]
    unique = [pairs[i] for i in order]
    dup_idx = rng.choice(len(unique), size=spec.n_duplicates, replace=spec.n_duplicates > len(unique))
    chosen = unique + [unique[i] for i in dup_idx]
    return [chosen[i] for i in rng.permutation(len(chosen))]


def _sample_disc_point(rng: np.random.Generator, radius: float) -> np.ndarray:
    r, a = radius * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
    return np.array([r * np.cos(a), r * np.sin(a)])


def _group_centres(spec: SceneSpec, rng: np.random.Generator, tries: int = 2000) -> np.ndarray:
    """Rejection-sample group centres on the table top, pairwise at least group_separation apart."""
    lim = np.array(spec.table_size) / 2 - spec.group_radius * 0.6
    centres: list[np.ndarray] = []
    for _ in range(tries):
        cand = rng.uniform(-lim, lim)
        if all(np.linalg.norm(cand - c) >= spec.group_separation for c in centres):
            centres.append(cand)
            if len(centres) == spec.n_groups:
                return np.array(centres)
    raise ValueError(
        f"spec {spec.name!r}: cannot fit n_groups={spec.n_groups} at group_separation={spec.group_separation}"
    )


def _place(
    spec: SceneSpec,
    rng: np.random.Generator,
    centres: np.ndarray,
    group: int,
    radius: float,
    placed: list[tuple[np.ndarray, float]],
    tries: int = 300,
) -> np.ndarray | None:
    """A free table position near the object's group centre, falling back to the other groups."""
    table_half = np.array(spec.table_size) / 2
    for g in np.roll(np.arange(len(centres)), -group):
        for _ in range(tries):
            xy = centres[g] + _sample_disc_point(rng, spec.group_radius)
            inside = np.all(np.abs(xy) + radius + 0.02 <= table_half)
            if inside and all(np.linalg.norm(xy - q) >= radius + r + spec.object_gap for q, r in placed):
                return xy
    return None


def _object_pieces(spec: SceneSpec, rng: np.random.Generator) -> list[Piece]:
    """Sample each object in its local frame, then place it in its group without overlaps."""
    centres = _group_centres(spec, rng)
    placed: list[tuple[np.ndarray, float]] = []
    pieces: list[Piece] = []
    for i, (colour, kind) in enumerate(choose_objects(spec, rng)):
        parts = KINDS[kind](float(rng.uniform(*spec.size_range)))
        pts, nrm, rgb = _sample_parts(rng, parts, spec.object_density, COLOURS[colour])
        radius = float(np.hypot(pts[:, 0], pts[:, 1]).max())
        xy = _place(spec, rng, centres, i % spec.n_groups, radius, placed)
        if xy is None:
            raise ValueError(
                f"spec {spec.name!r}: cannot place object {i} ({colour} {kind}); lower n_objects or widen group_radius"
            )
        placed.append((xy, radius))
        rot = yaw_rotation(float(rng.uniform(0.0, 2 * np.pi)))
        offset = np.array([xy[0], xy[1], spec.table_height])
        pieces.append(
            Piece(
                object_name(colour, kind),
                kind,
                colour,
                "object",
                pts @ rot.T + offset,
                nrm @ rot.T,
                rgb,
                spec.object_density,
                rot,
                offset,
            )
        )
    return pieces


def oriented_box(
    points: np.ndarray, rotation: np.ndarray, margin: float = 1e-4
) -> tuple[np.ndarray, np.ndarray]:
    """Centre and full extents of the box with the given axes that encloses the points."""
    local = points @ rotation
    lo, hi = local.min(axis=0) - margin, local.max(axis=0) + margin
    return rotation @ ((lo + hi) / 2), hi - lo


def build_scene(spec: SceneSpec) -> SyntheticScene:
    """The scene's Gaussians (room first, then objects) and its ground-truth instances."""
    rng = np.random.default_rng(spec.seed)
    room = _room_pieces(spec, rng)
    objects = _object_pieces(spec, rng)
    # Capture effects draw from their own stream: with them off, nothing above or below changes.
    capture_rng = np.random.default_rng([spec.seed, 3])
    pieces = (
        room
        + objects
        + capture.occluder_pieces(spec, capture_rng)
        + capture.clutter_pieces(spec, capture_rng, objects)
    )
    capture.apply_texture(spec, pieces, capture_rng)
    labelled = capture.add_labels(spec, pieces, capture_rng, first_object=len(room))
    points = np.concatenate([p.points for p in pieces])
    normals = np.concatenate([p.normals for p in pieces])
    rgb = np.concatenate([p.rgb for p in pieces])
    sigma = np.concatenate(
        [np.full(len(p.points), spec.tangential_scale / np.sqrt(p.density)) for p in pieces]
    )
    ids = np.repeat(np.arange(len(pieces), dtype=np.int32), [len(p.points) for p in pieces])
    gaussians = surfels_to_gaussians(points, normals, rgb, sigma, spec, rng)
    starts = np.concatenate([[0], np.cumsum([len(p.points) for p in pieces])])
    label_of: dict[int, str] = {}
    labels: list[Label] = []
    label_gaussians = np.zeros(len(points), dtype=bool) if labelled else None
    for index, colour, normal, mask in labelled:
        rows = starts[index] + np.flatnonzero(mask)
        paint_label(gaussians, rows, normals[rows], colour, normal, spec.label_half_angle_deg, spec)
        label_of[index] = colour
        labels.append(Label(index, colour, normal))
        assert label_gaussians is not None
        label_gaussians[rows] = True
    instances = []
    for i, piece in enumerate(pieces):
        centre, extents = oriented_box(gaussians.means[ids == i].astype(np.float64), piece.frame_rotation)
        instances.append(
            Instance(
                i,
                piece.name,
                piece.kind,
                piece.colour,
                piece.category,
                centre,
                piece.frame_rotation,
                extents,
                len(piece.points),
                label_of.get(i),
            )
        )
    top = np.array([0.0, 0.0, spec.table_height])
    return SyntheticScene(spec, gaussians, ids, instances, top, labels, label_gaussians)
