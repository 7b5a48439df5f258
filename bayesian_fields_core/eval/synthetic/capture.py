"""Capture effects of handheld scans that the orbiting suite never shows (issue #14, paper Fig. 3).

The paper's outlier rejection (OR-phi) and Bayesian updating are built for views whose CLIP score
to a task is unreliable: close-ups of an unrecognisable part, far views where an object spans a
few pixels, objects cut by the image border or hidden behind furniture, and objects whose
distinguishing feature (a label) faces the camera only from some sides. This module holds the
geometry of those effects; every effect is a `SceneSpec` field whose default switches it off,
and each draws from its own seeded stream, so default scenes are bit-identical to before.

- `extra_pieces`: occluders (furniture-like boxes and posts between the cameras and the table)
  and clutter (small neutral items on the table, background, never a task's answer);
- `apply_texture`: stripes on objects and a checker on the room instead of flat colour;
- `add_labels`: a coloured label patch on one side of some objects, whose colour is
  view-dependent (degree-1 SH) so it reads as the label only within `label_half_angle_deg` of
  the direction it faces;
- `walk_frames` / `cut_at_border`: a handheld walk at varying distance and height, and frames
  re-aimed so an object is cut by the image border.
"""

from __future__ import annotations

import numpy as np

from bayesian_fields_core.eval.synthetic.pieces import Piece, SyntheticScene, yaw_rotation
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.vocabulary import COLOURS, LABELLED_KINDS, NEUTRALS, Part, sample_part
from bayesian_fields_core.geometry.transforms import look_at, pinhole
from bayesian_fields_core.scene.types import Frame

_LABEL_OFFSET = 0.002  # the label floats this far (m) in front of the surface, so it is never hidden


def _neutral_rgb(rng: np.random.Generator) -> np.ndarray:
    """A desaturated colour far from the vocabulary's saturated ones (clutter is never a task)."""
    grey = rng.uniform(0.3, 0.75)
    return np.clip(grey + rng.normal(0.0, 0.03, 3), 0.0, 1.0)


def _box_piece(
    name: str,
    half: np.ndarray,
    centre_xy: np.ndarray,
    base_z: float,
    yaw_angle: float,
    rgb: np.ndarray,
    density: float,
    rng: np.random.Generator,
) -> Piece:
    part = Part("box", {"hx": half[0], "hy": half[1], "hz": half[2]}, translation=(0.0, 0.0, half[2]))
    pts, nrm = sample_part(rng, part, density)
    rot = yaw_rotation(yaw_angle)
    offset = np.array([centre_xy[0], centre_xy[1], base_z])
    rgbs = np.broadcast_to(rgb, pts.shape).copy()
    return Piece(name, name, None, "background", pts @ rot.T + offset, nrm @ rot.T, rgbs, density, rot)


def occluder_pieces(spec: SceneSpec, rng: np.random.Generator) -> list[Piece]:
    """`spec.n_occluders` furniture pieces standing just outside the table's edge.

    Alternately a tall post (a shelf upright or floor lamp, taller than the cameras) and a
    chair-back-like panel facing the table, 0.1-0.3 m beyond the edge: a camera on the far side
    of one sees the near objects partly hidden. They stay inside the orbit (orbit cameras never
    stand in one); walk cameras that would are moved out (`_push_out_of_boxes`).
    """
    table_half = np.array(spec.table_size) / 2
    pieces = []
    for i in range(spec.n_occluders):
        post = i % 2 == 0
        half = (
            np.array([0.06, 0.06, rng.uniform(0.8, 0.95)])
            if post
            else np.array([rng.uniform(0.2, 0.28), 0.04, rng.uniform(0.5, 0.6)])
        )
        angle = rng.uniform(0.0, 2 * np.pi)
        ray = np.array([np.cos(angle), np.sin(angle)])
        to_edge = float(np.min(table_half / np.maximum(np.abs(ray), 1e-9)))
        xy = (to_edge + rng.uniform(0.1, 0.3) + half[1]) * ray
        # A panel faces the table centre (its thin axis radial); a post is turned at random.
        heading = float(angle + np.pi / 2) if not post else float(rng.uniform(0, np.pi))
        colour = np.asarray(NEUTRALS["metal"] if post else NEUTRALS["wood"]) * rng.uniform(0.8, 1.2)
        pieces.append(
            _box_piece("occluder", half, xy, 0.0, heading, np.clip(colour, 0, 1), spec.table_density * 2, rng)
        )
    return pieces


def clutter_pieces(
    spec: SceneSpec, rng: np.random.Generator, objects: list[Piece], tries: int = 300
) -> list[Piece]:
    """`spec.n_clutter` small neutral boxes on the table, near the objects but not inside them.

    Placed close to objects (within 0.12 m of a footprint), they touch them in the images, so a
    segmenter merges them with their neighbour or splits them off: under-segmentation.
    """
    table_half = np.array(spec.table_size) / 2
    footprints = [
        (p.points[:, :2].mean(axis=0), float(np.ptp(p.points[:, :2], axis=0).max() / 2)) for p in objects
    ]
    pieces: list[Piece] = []
    for _ in range(spec.n_clutter):
        half = np.array([rng.uniform(0.012, 0.03), rng.uniform(0.012, 0.03), rng.uniform(0.008, 0.03)])
        reach = float(np.hypot(half[0], half[1]))
        for _ in range(tries):
            anchor, r = footprints[rng.integers(len(footprints))] if footprints else (np.zeros(2), 0.0)
            a = rng.uniform(0, 2 * np.pi)
            xy = anchor + (r + reach + rng.uniform(0.005, 0.12)) * np.array([np.cos(a), np.sin(a)])
            inside = np.all(np.abs(xy) + reach <= table_half - 0.02)
            if inside and all(np.linalg.norm(xy - c) >= rr + reach + 0.005 for c, rr in footprints):
                break
        else:
            continue
        footprints.append((xy, reach))
        pieces.append(
            _box_piece(
                "clutter",
                half,
                xy,
                spec.table_height,
                float(rng.uniform(0, np.pi)),
                _neutral_rgb(rng),
                spec.object_density,
                rng,
            )
        )
    return pieces


def apply_texture(spec: SceneSpec, pieces: list[Piece], rng: np.random.Generator) -> None:
    """Stripes on objects (horizontal bands, random phase and tilt) and a checker on the room.

    Multiplies each piece's RGB in place by 1 or (1 - texture_contrast): a segmenter that cuts at
    colour edges now splits an object into bands (over-segmentation) unless it merges them.
    """
    if spec.texture == "flat":
        return
    period, dark = spec.texture_period, 1.0 - spec.texture_contrast
    for piece in pieces:
        pts = piece.points
        if piece.category == "object":
            on = stripes(pts, period, rng)
        else:
            cell = np.floor(pts / (4 * period)).astype(int)
            on = cell.sum(axis=1) % 2 == 1
        piece.rgb = np.asarray(piece.rgb, dtype=np.float64) * np.where(on, dark, 1.0)[:, None]


def stripes(points: np.ndarray, period: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) bool: the dark bands of horizontal stripes of `period` (m) with a random small tilt
    and phase, over an object's surface points (n, 3)."""
    tilt = rng.normal(0.0, 0.3, 2)
    coord = points[:, 2] + points[:, :2] @ tilt + rng.uniform(0, period)
    return np.floor(coord / period).astype(int) % 2 == 1


def add_labels(
    spec: SceneSpec, pieces: list[Piece], rng: np.random.Generator, first_object: int
) -> list[tuple[int, str, np.ndarray, np.ndarray]]:
    """Give `spec.n_labelled` objects a label patch on their local +y side.

    One copy of each duplicated object is labelled first, so a task naming the label has a look-alike that is
    not its answer. Appends the patch's surfels to the object's piece and returns
    (piece index, label colour, world normal, boolean mask of the piece's label surfels).
    """
    candidates = [i for i in range(first_object, len(pieces)) if pieces[i].kind in LABELLED_KINDS]
    names = [pieces[i].name for i in candidates]
    duplicated = [i for i, n in zip(candidates, names, strict=True) if names.count(n) > 1]
    # One per duplicated name first, then the rest in seeded order.
    order: list[int] = []
    for i in duplicated:
        if pieces[i].name not in {pieces[j].name for j in order}:
            order.append(i)
    # Then the others in seeded order, copies of an already labelled object last (so it keeps
    # an unlabelled look-alike).
    rest = [i for i in candidates if i not in order]
    rest = [rest[k] for k in rng.permutation(len(rest))]
    labelled_names = {pieces[j].name for j in order}
    order += [i for i in rest if pieces[i].name not in labelled_names]
    order += [i for i in rest if pieces[i].name in labelled_names]
    out: list[tuple[int, str, np.ndarray, np.ndarray]] = []
    for index in order[: spec.n_labelled]:
        piece = pieces[index]
        size = float(np.ptp(piece.points @ piece.frame_rotation, axis=0)[2]) / (
            2 * LABELLED_KINDS[piece.kind][1]
        )
        pts, nrm = sample_part(rng, label_part(piece.kind, size, spec.label_size), spec.object_density)
        base, rot = piece.origin, piece.frame_rotation
        # Copies of one object get different label colours, so every label task has one answer.
        taken = {c for j, c, _, _ in out if pieces[j].name == piece.name}
        colours = [c for c in COLOURS if c != piece.colour and c not in taken]
        colour = colours[rng.integers(len(colours))]
        n_before = len(piece.points)
        piece.points = np.concatenate([piece.points, pts @ rot.T + base])
        piece.normals = np.concatenate([piece.normals, nrm @ rot.T])
        assert piece.colour is not None
        piece.rgb = np.concatenate([piece.rgb, np.broadcast_to(COLOURS[piece.colour], pts.shape)])
        mask = np.zeros(len(piece.points), dtype=bool)
        mask[n_before:] = True
        out.append((index, colour, rot[:, 1].copy(), mask))
    return out


def label_part(kind: str, size: float, label_size: float) -> Part:
    """The label patch of an object of `kind` and size factor `size`: a square of half side
    `label_size * size` facing local +y, just in front of the surface (object coordinates)."""
    surface, height = (v * size for v in LABELLED_KINDS[kind])
    half = label_size * size
    return Part(
        "rect",
        {"hx": half, "hy": half},
        rotation=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
        translation=(0.0, surface + _LABEL_OFFSET, height),
    )


def label_sh(
    object_rgb: np.ndarray, label_rgb: np.ndarray, normal: np.ndarray, half_angle_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Degree-0 and degree-1 SH coefficients that show `label_rgb` head-on and `object_rgb`
    beyond `half_angle_deg` from `normal`.

    The renderer's colour is ``0.5 + C0 * f0 + C1 * (-y f1 + z f2 - x f3)`` for the unit direction
    (x, y, z) from the camera to the Gaussian; with t = -direction . normal (1 head-on, 0 edge-on)
    the colour is ``object + (t - cos h) / (1 - cos h) * (label - object)``, linear in t: the label
    colour at t = 1, the object's at the cone's edge, and beyond it (clamped by the renderer) the
    object's colour pushed away from the label's, which still reads as the object.
    object_rgb, label_rgb: (n, 3) shaded colours; returns f_dc (n, 3) and f_rest (n, 3, 3).
    """
    from bayesian_fields_core.geometry.spherical_harmonics import C1, SH_C0

    cos_h = float(np.cos(np.deg2rad(half_angle_deg)))
    a = 1.0 / (1.0 - cos_h)
    delta = label_rgb - object_rgb
    dc = object_rgb - a * cos_h * delta
    f_dc = (dc - 0.5) / SH_C0
    n = np.asarray(normal, dtype=np.float64)
    # -C1*y*f1 + C1*z*f2 - C1*x*f3 = -a (x nx + y ny + z nz) delta
    f_rest = np.stack([a * n[1] * delta / C1, -a * n[2] * delta / C1, a * n[0] * delta / C1], axis=1)
    return f_dc, f_rest


def _smooth(rng: np.random.Generator, n: int, waves: int = 3) -> np.ndarray:
    """A smooth random signal in [0, 1] over n frames (a few sinusoids with random phases)."""
    t = np.linspace(0.0, 1.0, n)
    s = sum(
        np.sin(2 * np.pi * (k + 1) * t * rng.uniform(0.6, 1.4) + rng.uniform(0, 2 * np.pi)) / (k + 1)
        for k in range(waves)
    )
    s = np.asarray(s, dtype=np.float64)
    return (s - s.min()) / max(float(np.ptp(s)), 1e-9)


def _object_centres(scene: SyntheticScene) -> np.ndarray:
    return np.array([i.center for i in scene.instances if i.category == "object"])


def _push_out_of_boxes(eye: np.ndarray, scene: SyntheticScene, margin: float = 0.15) -> np.ndarray:
    """Move an eye that stands inside (or too near) an occluder sideways, out of it."""
    for inst in scene.instances:
        if inst.name != "occluder":
            continue
        local = inst.rotation.T @ (eye - inst.center)
        reach = inst.extents / 2 + margin
        if np.all(np.abs(local) <= reach):
            # Out through the nearer vertical side.
            axis = int(np.argmin((reach - np.abs(local))[:2]))
            local[axis] = np.copysign(reach[axis], local[axis] if local[axis] != 0 else 1.0)
            eye = inst.center + inst.rotation @ local
    return eye


def walk_frames(
    spec: SceneSpec, scene: SyntheticScene, rng: np.random.Generator, prefix: str = "frame"
) -> list[Frame]:
    """A handheld walk: once around the table at a smoothly varying distance to the object looked
    at (``walk_distance``, log-spaced: close-ups that overfill the frame to far views where an
    object spans a few pixels) and a varying height, looking at one object after another.
    """
    n = spec.n_frames
    centres = _object_centres(scene)
    order = rng.permutation(len(centres))
    dwell = max(1, n // max(1, len(centres)))
    lo, hi = np.log(spec.walk_distance[0]), np.log(spec.walk_distance[1])
    distance = np.exp(lo + (hi - lo) * _smooth(rng, n))
    azimuth = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n) / n + rng.normal(0, 0.05, n)
    low, high = spec.walk_elevation_deg
    elevation = np.deg2rad(low + (high - low) * _smooth(rng, n))
    half_room = spec.room_size / 2 - 0.1
    K = pinhole(spec.width, spec.height, spec.fov_deg)
    frames = []
    for i in range(n):
        target = centres[order[(i // dwell) % len(centres)]] + rng.normal(0, 0.01, 3)
        direction = np.array(
            [
                np.cos(elevation[i]) * np.cos(azimuth[i]),
                np.cos(elevation[i]) * np.sin(azimuth[i]),
                np.sin(elevation[i]),
            ]
        )
        eye = target + distance[i] * direction
        eye[:2] = np.clip(eye[:2], -half_room, half_room)
        eye[2] = np.clip(eye[2], spec.table_height + 0.12, spec.wall_height - 0.1)
        eye = _push_out_of_boxes(eye, scene)
        frames.append(
            Frame(
                name=f"{prefix}_{i:05d}.png",
                K=K.copy(),
                world_to_camera=look_at(eye, target),
                width=spec.width,
                height=spec.height,
            )
        )
    return frames


def cut_at_border(
    frames: list[Frame], spec: SceneSpec, scene: SyntheticScene, rng: np.random.Generator
) -> list[int]:
    """Re-aim a `border_cut_share` of the frames so an object's centre sits on the left or right
    image border (the object is cut in about half); returns the re-aimed frame indices.

    The camera keeps its position and turns about the world's up axis by half the horizontal
    field of view, so the object it looked at moves to the border.
    """
    n_cut = int(round(spec.border_cut_share * len(frames)))
    if n_cut == 0:
        return []
    centres = _object_centres(scene)
    chosen = sorted(int(i) for i in rng.choice(len(frames), size=n_cut, replace=False))
    half_fov = np.deg2rad(spec.fov_deg) / 2
    for i in chosen:
        frame = frames[i]
        rot, t = frame.world_to_camera[:3, :3], frame.world_to_camera[:3, 3]
        eye = -rot.T @ t
        # The nearest object in front of the camera (it fills the view most).
        forward = rot[2]
        ahead = [c for c in centres if (c - eye) @ forward > 0.1] or list(centres)
        target = min(ahead, key=lambda c: float(np.linalg.norm(c - eye)))
        side = rng.choice([-1.0, 1.0])
        angle = side * half_fov
        c, s = np.cos(angle), np.sin(angle)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        frame.world_to_camera = look_at(eye, eye + turn @ (target - eye))
    return chosen
