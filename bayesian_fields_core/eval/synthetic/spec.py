"""Named, validated parameters of a synthetic benchmark scene, and the scenes of the eval suite.

Every number that shapes a scene lives here with its default, so a scene is reproducible from its
spec alone (the spec is written into ``gt.json``) and the eval suite is a list of specs.
"""

from __future__ import annotations

from collections.abc import Sequence

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
        return self


SUITE_SIZE = 5


def suite_specs(seeds: Sequence[int] | None = None) -> list[SceneSpec]:
    """Five modest scenes (~35-60k Gaussians, 24-32 frames at 320x240) for ``bfields eval``.

    They differ in seed, clutter, colour reuse and grouping, so the suite exercises fine tasks
    with duplicates, coarse colour/kind tasks, compounds and absent-object tasks.

    `seeds` re-seeds the first ``len(seeds)`` specs (same clutter and camera layout, different
    objects, colours, placements and tasks) and renames them ``<name>-s<seed>``: held-out scenes
    for checking that a choice made while looking at the suite carries over to scenes it was
    not made on.
    """
    specs = _suite_layouts()
    if seeds is None:
        return specs
    if not 1 <= len(seeds) <= len(specs):
        raise ValueError(f"give 1 to {len(specs)} seeds, got {len(seeds)}")
    if min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct and >= 0, got {list(seeds)}")
    return [
        spec.model_copy(update={"seed": int(seed), "name": f"{spec.name}-s{seed}"})
        for spec, seed in zip(specs, seeds, strict=False)
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
