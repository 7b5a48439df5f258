"""Named, validated parameters of a synthetic benchmark scene, and the scenes of the eval suite.

Every number that shapes a scene lives here with its default, so a scene is reproducible from its
spec alone (the spec is written into ``gt.json``) and the eval suite is a list of specs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from bayesian_fields_core.eval.vocabulary import COLOURS, KINDS


class SceneSpec(BaseModel):
    """A tabletop in a room with coloured objects in separate groups, seen by an orbiting camera.

    Densities are Gaussians per square metre of surface; each Gaussian is a flat disc whose
    in-plane standard deviation is ``tangential_scale / sqrt(density)`` (so neighbours overlap and
    the surface renders closed) and whose thickness is ``flatness`` times that.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = "synthetic"
    seed: int = 0
    # Objects.
    n_objects: int = Field(10, ge=1, le=40, description="objects on the table, compounds included")
    n_duplicates: int = Field(2, ge=0, description="objects that repeat another's colour and kind")
    n_colours: int = Field(5, ge=1, le=len(COLOURS), description="distinct colours used by the objects")
    kinds: tuple[str, ...] = tuple(KINDS)
    n_groups: int = Field(3, ge=1, description="spatially separate clusters of objects on the table")
    group_radius: float = Field(
        0.28, gt=0, description="objects lie within this distance of their group centre (m)"
    )
    group_separation: float = Field(0.5, gt=0, description="minimum distance between group centres (m)")
    object_gap: float = Field(0.03, ge=0, description="minimum clearance between object footprints (m)")
    size_range: tuple[float, float] = (0.9, 1.15)
    # Room and table (metres; z up, table centred on the origin).
    room_size: float = Field(4.0, gt=0)
    wall_height: float = Field(2.0, gt=0)
    table_size: tuple[float, float] = (1.6, 1.0)
    table_height: float = Field(0.75, gt=0)
    # Gaussians.
    object_density: float = Field(25000.0, gt=0)
    table_density: float = Field(2500.0, gt=0)
    room_density: float = Field(500.0, gt=0)
    tangential_scale: float = Field(1.0, gt=0)
    flatness: float = Field(0.1, gt=0, le=1)
    opacity: float = Field(0.95, gt=0, lt=1)
    colour_noise: float = Field(0.03, ge=0, description="std of per-Gaussian RGB noise")
    light_direction: tuple[float, float, float] = (0.35, 0.55, 1.0)
    ambient: float = Field(0.55, ge=0, le=1, description="share of the colour lit regardless of the normal")
    sh_degree: int = Field(0, ge=0, le=3, description="higher-degree coefficients are written as zeros")
    # Cameras: an orbit around the table centre, alternating between the given heights.
    width: int = Field(320, ge=16)
    height: int = Field(240, ge=16)
    fov_deg: float = Field(60.0, gt=10, lt=150, description="horizontal field of view")
    n_frames: int = Field(32, ge=1)
    orbit_radius: float = Field(1.5, gt=0)
    orbit_heights: tuple[float, ...] = (1.3, 1.6)
    orbit_jitter: float = Field(0.05, ge=0, description="random offset of camera positions (m)")
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Tasks.
    max_fine_tasks: int = Field(8, ge=0)
    max_coarse_tasks: int = Field(3, ge=0)
    n_absent_tasks: int = Field(1, ge=0)
    # Capture effects (eval/synthetic/capture.py); the defaults switch them all off.
    trajectory: Literal["orbit", "walk"] = Field(
        "orbit", description="orbit: the ring above; walk: a handheld path at varying distance and height"
    )
    walk_distance: tuple[float, float] = (0.3, 2.2)
    walk_elevation_deg: tuple[float, float] = (10.0, 45.0)
    border_cut_share: float = Field(
        0.0, ge=0, le=1, description="share of frames re-aimed so an object is cut by the image border"
    )
    n_occluders: int = Field(0, ge=0, le=8, description="posts and cabinets between cameras and table")
    n_clutter: int = Field(0, ge=0, le=40, description="small neutral items on the table (never a task)")
    texture: Literal["flat", "stripes"] = Field(
        "flat", description="stripes: banded objects and a checkered room instead of flat colours"
    )
    texture_period: float = Field(0.04, gt=0, description="stripe width (m); the room's checker is 4x")
    texture_contrast: float = Field(0.6, ge=0, lt=1, description="darkening of the dark stripes")
    n_labelled: int = Field(
        0, ge=0, description="objects with a coloured label on one side, and a task naming it"
    )
    label_half_angle_deg: float = Field(
        50.0, gt=0, lt=90, description="the label reads as its colour within this angle of its normal"
    )
    label_size: float = Field(0.03, gt=0, description="half side of the label per unit object size (m)")
    outlier_share: float = Field(
        0.0,
        ge=0,
        le=1,
        description="share of frames replaced by near, far and occluded views of task objects "
        "(the outlier dial, synthetic/outliers.py)",
    )

    @model_validator(mode="after")
    def _check(self) -> SceneSpec:
        unknown = [k for k in self.kinds if k not in KINDS]
        if unknown:
            raise ValueError(f"kinds: unknown {unknown}; known {sorted(KINDS)}")
        if self.n_duplicates >= self.n_objects:
            raise ValueError("n_duplicates must be smaller than n_objects")
        if self.n_objects - self.n_duplicates > self.n_colours * len(self.kinds):
            raise ValueError("n_objects - n_duplicates exceeds the distinct (colour, kind) pairs available")
        if self.orbit_radius + self.orbit_jitter >= self.room_size / 2:
            raise ValueError("orbit_radius must keep the cameras inside the room")
        if not self.orbit_heights:
            raise ValueError("orbit_heights must not be empty")
        if self.n_labelled > 0 and self.sh_degree < 1:
            raise ValueError("n_labelled > 0 needs sh_degree >= 1 (the label's colour is view-dependent)")
        if not 0 < self.walk_distance[0] < self.walk_distance[1]:
            raise ValueError("walk_distance must be (near, far) with 0 < near < far")
        if self.outlier_share > 0 and self.n_occluders < 1:
            raise ValueError("outlier_share > 0 needs n_occluders >= 1 (its occluded views stand behind one)")
        return self

    def ground_truth_dump(self) -> dict:
        """The spec for gt.json: capture fields left at their defaults are omitted, so scenes made
        before they existed keep byte-identical ground-truth files."""
        skip = {
            name for name in CAPTURE_FIELDS if getattr(self, name) == SceneSpec.model_fields[name].default
        }
        return self.model_dump(mode="json", exclude=skip)


CAPTURE_FIELDS: tuple[str, ...] = (
    "trajectory",
    "walk_distance",
    "walk_elevation_deg",
    "border_cut_share",
    "n_occluders",
    "n_clutter",
    "texture",
    "texture_period",
    "texture_contrast",
    "n_labelled",
    "label_half_angle_deg",
    "label_size",
    "outlier_share",
)
SUITE_SIZE = 5
"""Scene layouts per suite (clutter, camera path, object counts)."""

PUBLIC_RESEEDS: tuple[int, ...] = (1201, 1301, 1401, 1501, 1601)
"""Public seeds of suite scenes 6-10: the five layouts again with these seeds. Decisions such as
issue 23's are taken on all ten public scenes, where five give intervals too wide to decide;
held-out checks use seeds outside this list and the layouts' own."""

MAX_SUITE_SCENES = SUITE_SIZE + len(PUBLIC_RESEEDS)

MAX_HELD_OUT_SCENES = 40
"""Most held-out seeds one run takes. Issue 33 asks for at least 20 held-out scenes per suite,
because its intervals resample scenes and ten scenes give intervals too wide to decide."""


SUITES: tuple[str, ...] = ("tabletop", "capture")


def suite_specs(seeds: Sequence[int] | None = None, suite: str = "tabletop") -> list[SceneSpec]:
    """Modest scenes (~35-60k Gaussians, 24-32 frames at 320x240) for ``bfields eval``.

    They differ in seed, clutter, colour reuse and grouping, so the suite exercises fine tasks
    with duplicates, coarse colour/kind tasks, compounds and absent-object tasks.

    Without `seeds`: the five layouts with their own seeds, then the same five re-seeded with
    `PUBLIC_RESEEDS` (ten public scenes; callers take the first n).

    `seeds` re-seeds the layouts in turn (seed i goes to layout i mod 5: same clutter and camera
    layout, different objects, colours, placements and tasks) and renames them
    ``<name>-s<seed>``: held-out scenes for checking that a choice made while looking at the
    suite carries over to scenes it was not made on.

    `suite` names the suite: "tabletop" (orbiting cameras, whole objects) or "capture" (the
    handheld-capture effects of `capture_layouts`).
    """
    if suite not in SUITES:
        raise ValueError(f"unknown suite {suite!r}; known: {', '.join(SUITES)}")
    specs = _suite_layouts() if suite == "tabletop" else capture_layouts()
    if seeds is None:
        return specs + _reseeded(specs, PUBLIC_RESEEDS)
    if not 1 <= len(seeds) <= MAX_HELD_OUT_SCENES:
        raise ValueError(f"give 1 to {MAX_HELD_OUT_SCENES} seeds, got {len(seeds)}")
    if min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct and >= 0, got {list(seeds)}")
    return _reseeded(specs, seeds)


def _reseeded(specs: list[SceneSpec], seeds: Sequence[int]) -> list[SceneSpec]:
    """Layout i mod len(specs) with seed i, named ``<layout>-s<seed>``."""
    return [
        specs[i % len(specs)].model_copy(
            update={"seed": int(seed), "name": f"{specs[i % len(specs)].name}-s{seed}"}
        )
        for i, seed in enumerate(seeds)
    ]


def _suite_layouts() -> list[SceneSpec]:
    return [
        SceneSpec(
            name="tabletop-a", seed=11, n_objects=8, n_duplicates=1, n_colours=4, n_groups=2, n_frames=24
        ),
        SceneSpec(
            name="tabletop-b", seed=23, n_objects=11, n_duplicates=2, n_colours=5, n_groups=3, n_frames=32
        ),
        SceneSpec(
            name="tabletop-c",
            seed=37,
            n_objects=13,
            n_duplicates=3,
            n_colours=6,
            n_groups=3,
            n_frames=32,
            orbit_radius=1.4,
            orbit_heights=(1.2, 1.5, 1.75),
            n_absent_tasks=2,
        ),
        SceneSpec(
            name="tabletop-d", seed=41, n_objects=10, n_duplicates=2, n_colours=5, n_groups=2, n_frames=28
        ),
        SceneSpec(
            name="tabletop-e",
            seed=53,
            n_objects=12,
            n_duplicates=2,
            n_colours=6,
            n_groups=3,
            n_frames=28,
            orbit_radius=1.5,
            orbit_heights=(1.25, 1.6),
        ),
    ]


def capture_layouts() -> list[SceneSpec]:
    """Five scenes with the effects of handheld captures (paper Fig. 3): walks at varying distance
    (close-ups, far views), border cuts, occluding furniture, labels readable from one side, with
    look-alike duplicates, striped textures and clutter. Each mixes the effects differently."""
    common: dict[str, Any] = {
        "trajectory": "walk",
        "texture": "stripes",
        "sh_degree": 1,
        "n_frames": 32,
    }
    return [
        SceneSpec(
            name="capture-a",
            seed=61,
            n_objects=8,
            n_duplicates=2,
            n_colours=4,
            n_groups=2,
            n_labelled=2,
            n_occluders=2,
            n_clutter=6,
            border_cut_share=0.2,
            **common,
        ),
        SceneSpec(
            name="capture-b",
            seed=73,
            n_objects=10,
            n_duplicates=2,
            n_colours=5,
            n_groups=3,
            n_labelled=2,
            n_occluders=3,
            n_clutter=8,
            border_cut_share=0.15,
            **common,
        ),
        SceneSpec(
            name="capture-c",
            seed=89,
            n_objects=11,
            n_duplicates=3,
            n_colours=5,
            n_groups=3,
            n_labelled=3,
            n_occluders=2,
            n_clutter=10,
            border_cut_share=0.25,
            walk_distance=(0.25, 2.4),
            n_absent_tasks=2,
            **common,
        ),
        SceneSpec(
            name="capture-d",
            seed=97,
            n_objects=9,
            n_duplicates=2,
            n_colours=4,
            n_groups=2,
            n_labelled=2,
            n_occluders=4,
            n_clutter=4,
            border_cut_share=0.2,
            label_half_angle_deg=40.0,
            **common,
        ),
        SceneSpec(
            name="capture-e",
            seed=103,
            n_objects=10,
            n_duplicates=2,
            n_colours=6,
            n_groups=3,
            n_labelled=2,
            n_occluders=3,
            n_clutter=8,
            border_cut_share=0.2,
            walk_distance=(0.3, 2.0),
            **common,
        ),
    ]
