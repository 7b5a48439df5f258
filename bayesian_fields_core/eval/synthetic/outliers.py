"""The outlier dial (issue 46, docs/research/ablation-decision.md): a share of a capture's frames
replaced by the views the paper's OR-phi is for (its Fig. 2b).

The paper rejects views whose cosine to a task is an outlier, "too far or too close (such as
revealing an incomprehensible occluded view of an object)", because they give "false low
probabilities". `SceneSpec.outlier_share` = S replaces ``round(S * n_frames)`` frames of the
capture by such views of the scene's task objects (the answers of its present tasks), the three
kinds in equal parts:

- **near**: the camera `NEAR_GAP` (m) outside the object's surface, looking at its centre, so
  the object overfills the frame and the image shows a few centimetres of its surface;
- **far**: the camera in the room's corner farthest from the object (at least
  `FAR_MIN_DISTANCE` from its centre), so the object spans a few pixels (about 10 at 320 px:
  the room's walls, which the renderer draws, bound how far a camera can stand);
- **occluded**: the camera just behind one of the scene's occluders (`capture.occluder_pieces`)
  on the line to the object, shifted sideways so that only a sliver of the object's width
  (`OCCLUDED_VISIBLE`) shows past the occluder's rendered edge (its box grown by
  `OCCLUDER_BLUR`); the ray to the object's centre meets that grown box.

Which frames, which kind, which object and every pose draw from their own stream ([seed, 5]), so
the other frames keep their poses, and scene, objects and tasks do not change; S = 0 replaces
nothing (today's scenes bit for bit). Scenes with S > 0 are named apart (`with_outliers`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayesian_fields_core.eval.synthetic.pieces import Instance, SyntheticScene
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.synthetic.tasks import make_tasks
from bayesian_fields_core.geometry.transforms import look_at
from bayesian_fields_core.scene.types import Frame

OutlierKind = Literal["near", "far", "occluded"]
OUTLIER_KINDS: tuple[OutlierKind, ...] = ("near", "far", "occluded")

NEAR_GAP = (0.02, 0.04)
"""Range (m) of a near view's gap between the camera and the object's surface: at 60 degrees
of horizontal field of view the frame spans 2.3 to 4.6 cm of surface there."""
FAR_MIN_DISTANCE = 2.2
"""A far view's camera stands at least this far (m) from its object's centre."""
OCCLUDED_VISIBLE = (0.2, 0.45)
"""Range of the share of the object's angular width left visible beside the occluder."""
OCCLUDER_GAP = (0.2, 0.45)
"""Range (m) of the distance from the occluder's back face to the camera in an occluded view."""
OCCLUDER_BLUR = 0.035
"""Margin (m) added to an occluder's box on each side when judging what it hides: its Gaussians
(1.4 to 2.2 cm wide) render as soft discs reaching past the box (measured in id renders of the
capture scenes: with this margin the geometric share left visible is an upper bound of the
rendered one)."""
_STREAM = 5  # the dial's seeded stream: [seed, 5]


@dataclass(frozen=True)
class OutlierView:
    """Frame `index` replaced by a `kind` view of instance `instance_id` (pose: world_to_camera)."""

    index: int
    kind: OutlierKind
    instance_id: int
    world_to_camera: np.ndarray  # (4, 4)

    def to_json(self) -> dict[str, object]:
        return {"frame": self.index, "kind": self.kind, "instance_id": self.instance_id}


def with_outliers(spec: SceneSpec, share: float) -> SceneSpec:
    """`spec` with the dial at `share`, renamed ``<name>-o<percent>`` when share > 0 (caches of
    the two never mix); share 0 returns the spec unchanged."""
    if share == 0:
        return spec
    return spec.model_copy(
        update={"outlier_share": float(share), "name": f"{spec.name}-o{int(round(100 * share)):02d}"}
    )


def _corners(inst: Instance) -> np.ndarray:
    """(8, 3) corners of the instance's oriented box."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    return inst.center + (signs * inst.extents / 2) @ inst.rotation.T


def surface_distance(inst: Instance, point: np.ndarray) -> float:
    """Distance (m) from `point` (3,) to the instance's oriented box (0 inside)."""
    local = np.abs(inst.rotation.T @ (np.asarray(point) - inst.center)) - inst.extents / 2
    return float(np.linalg.norm(np.maximum(local, 0.0)))


def ray_hits_box(origin: np.ndarray, target: np.ndarray, inst: Instance) -> bool:
    """Whether the segment origin -> target passes through the instance's oriented box (slabs)."""
    o = inst.rotation.T @ (np.asarray(origin) - inst.center)
    d = inst.rotation.T @ (np.asarray(target) - np.asarray(origin))
    half = inst.extents / 2
    lo, hi = 0.0, 1.0
    for axis in range(3):
        if abs(d[axis]) < 1e-12:
            if abs(o[axis]) > half[axis]:
                return False
            continue
        t0, t1 = sorted(((-half[axis] - o[axis]) / d[axis], (half[axis] - o[axis]) / d[axis]))
        lo, hi = max(lo, t0), min(hi, t1)
        if lo > hi:
            return False
    return True


def _near_pose(points: np.ndarray, centre: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A camera NEAR_GAP outside the object's surface where a ray from its centre (in a random
    direction slightly above horizontal) leaves it, looking back at the centre.

    points: (n, 3) the object's Gaussian centres; centre: (3,) its box centre. The surface point
    is the farthest of the points within 15 degrees of the ray (a cone's slope, not its rim)."""
    azimuth, elevation = rng.uniform(0, 2 * np.pi), np.deg2rad(rng.uniform(5.0, 35.0))
    direction = np.array(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
    )
    offsets = points - centre
    along = offsets @ direction
    near_ray = along > np.cos(np.deg2rad(15.0)) * np.linalg.norm(offsets, axis=1)
    reach = float(along[near_ray].max()) if near_ray.any() else float(along.max())
    eye = centre + (reach + rng.uniform(*NEAR_GAP)) * direction
    return look_at(eye, centre)


def _far_pose(inst: Instance, spec: SceneSpec, rng: np.random.Generator) -> np.ndarray:
    """A camera high in the room's corner opposite the object, looking at it."""
    half_room = spec.room_size / 2 - 0.1
    corner = -np.sign(inst.center[:2] + 1e-9) * half_room
    # Slide along one of the corner's walls, keeping the distance above FAR_MIN_DISTANCE.
    for _ in range(20):
        xy = corner.copy()
        axis = int(rng.integers(2))
        xy[axis] -= np.sign(corner[axis]) * rng.uniform(0.0, 0.5)
        eye = np.array([xy[0], xy[1], rng.uniform(1.3, spec.wall_height - 0.1)])
        if np.linalg.norm(eye - inst.center) >= FAR_MIN_DISTANCE:
            return look_at(eye, inst.center)
    eye = np.array([corner[0], corner[1], spec.wall_height - 0.1])
    return look_at(eye, inst.center)


def _azimuths(points: np.ndarray, eye: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Horizontal angle of `points` (n, 3) seen from `eye`, relative to the unit `axis` (2,)."""
    d = points[:, :2] - eye[:2]
    return np.arctan2(d @ np.array([-axis[1], axis[0]]), d @ axis)


def blurred(occluder: Instance) -> Instance:
    """The occluder's box grown by OCCLUDER_BLUR on each side: what it hides once rendered."""
    return Instance(
        occluder.id, occluder.name, occluder.kind, occluder.colour, occluder.category,
        occluder.center, occluder.rotation, occluder.extents + 2 * OCCLUDER_BLUR, occluder.n_gaussians,
    )  # fmt: skip


def _visible_share(eye: np.ndarray, inst: Instance, occluders: list[Instance]) -> float:
    """Share of the object's horizontal angular extent, from `eye`, that no occluder standing
    nearer than the object covers (each grown by its blur)."""
    axis = inst.center[:2] - eye[:2]
    reach = max(float(np.linalg.norm(axis)), 1e-9)
    axis = axis / reach
    obj = _azimuths(_corners(inst), eye, axis)
    samples = np.linspace(float(obj.min()), float(obj.max()), 64)
    covered = np.zeros(len(samples), dtype=bool)
    for occ in occluders:
        if float(np.linalg.norm(occ.center[:2] - eye[:2])) >= reach:
            continue
        az = _azimuths(_corners(blurred(occ)), eye, axis)
        covered |= (samples >= az.min()) & (samples <= az.max())
    return float(1.0 - covered.mean())


def _occluded_pose(
    inst: Instance, occluders: list[Instance], spec: SceneSpec, rng: np.random.Generator
) -> np.ndarray | None:
    """A camera behind an occluder (nearest the object first) on the line to the object, shifted
    sideways so about OCCLUDED_VISIBLE of the object shows; None when no occluder allows one."""
    half_room = spec.room_size / 2 - 0.1
    target_share = rng.uniform(*OCCLUDED_VISIBLE)
    gap = rng.uniform(*OCCLUDER_GAP)
    side = rng.choice([-1.0, 1.0])
    for occ in sorted(occluders, key=lambda o: float(np.linalg.norm(o.center[:2] - inst.center[:2]))):
        top = occ.center[2] + occ.extents[2] / 2
        z = float(np.clip(inst.center[2], spec.table_height + 0.05, top - 0.05))
        through = np.array([occ.center[0], occ.center[1], z])
        u = through - np.array([inst.center[0], inst.center[1], z])
        u /= max(float(np.linalg.norm(u)), 1e-9)
        perp = np.array([-u[1], u[0], 0.0])
        # The occluder's reach along u: the box's support in that direction.
        depth = float(np.sum(np.abs(occ.rotation.T @ u) * occ.extents / 2))
        base = through + (depth + gap) * u
        best: tuple[float, np.ndarray] | None = None
        for shift in np.linspace(0.0, 0.4, 161):
            eye = base + side * shift * perp
            if not np.all(np.abs(eye[:2]) <= half_room):
                continue
            if not ray_hits_box(eye, inst.center, blurred(occ)):
                continue
            err = abs(_visible_share(eye, inst, occluders) - target_share)
            if best is None or err < best[0]:
                best = (err, eye)
        if best is not None and best[0] < 0.1:
            return look_at(best[1], inst.center)
    return None


def task_object_ids(spec: SceneSpec, scene: SyntheticScene) -> list[int]:
    """Instance ids of the answers of the scene's tasks (the tasks `make_tasks` gives it)."""
    tasks = make_tasks(spec, scene.instances, np.random.default_rng([spec.seed, 2]))
    return sorted({i for t in tasks for i in t.instance_ids})


def outlier_views(spec: SceneSpec, scene: SyntheticScene, n_frames: int) -> list[OutlierView]:
    """The frames the dial replaces, in frame order: which kind, of which object, from where.

    Kinds cycle near, far, occluded in a seeded order (equal parts up to one); objects cycle
    through a seeded permutation of the task objects. An occluded view for which no occluder
    stands between a room position and the object goes to the next object."""
    n_out = int(round(spec.outlier_share * n_frames))
    if n_out == 0:
        return []
    rng = np.random.default_rng([spec.seed, _STREAM])
    by_id = {i.id: i for i in scene.instances}
    objects = [by_id[i] for i in task_object_ids(spec, scene)]
    occluders = [i for i in scene.instances if i.name == "occluder"]
    if not objects:
        return []
    chosen = sorted(int(i) for i in rng.choice(n_frames, size=n_out, replace=False))
    kinds = [OUTLIER_KINDS[k % 3] for k in range(n_out)]
    kinds = [kinds[k] for k in rng.permutation(n_out)]
    order = [objects[k] for k in rng.permutation(len(objects))]
    views: list[OutlierView] = []
    for k, (index, kind) in enumerate(zip(chosen, kinds, strict=True)):
        pose: np.ndarray | None = None
        for step in range(len(order)):
            inst = order[(k + step) % len(order)]
            if kind == "near":
                pose = _near_pose(scene.gaussians.means[scene.instance_ids == inst.id], inst.center, rng)
            elif kind == "far":
                pose = _far_pose(inst, spec, rng)
            else:
                pose = _occluded_pose(inst, occluders, spec, rng)
            if pose is not None:
                break
        if pose is None:
            raise ValueError(f"{spec.name}: no occluded view of any task object")
        views.append(OutlierView(index, kind, inst.id, pose))
    return views


def apply_outliers(frames: list[Frame], views: list[OutlierView]) -> None:
    """Give the replaced frames their outlier poses (in place; names and intrinsics stay)."""
    for view in views:
        frames[view.index].world_to_camera = view.world_to_camera.copy()
