"""The cache keys of existing parameters never change when the code that declares them moves.

A changed key silently orphans every cache a user has built (each scene re-runs perception and
visibility from scratch), so the keys of the bundled sample's second frame are pinned here for
the default parameters and a few variations, and the parameter part of the alignment verdict's. The values were recorded on main before the
parameters started to declare their stage in their own `Field` (issue 32, item 2); if one of
them changes, the change is a cache-format break and needs saying in the changelog, not a new
expected value.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.job.cache_keys import CacheKeys, short_hash
from bayesian_fields_core.job.stage_table import ALIGNMENT_CACHE, cache_parameters
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.scale import scene_lengths
from bayesian_fields_core.scene.types import Scene

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"

VARIATIONS: dict[str, dict[str, object]] = {
    "default": {},
    "depth_source": {"depth_source": "expected"},
    "scene_scale": {"scene_scale": 3.0},
    "depth_tolerance": {"depth_tolerance": 0.123},
    "depth_tolerance_scene": {"depth_tolerance_scene": 0.05},
    "depth_tolerance_relative": {"depth_tolerance_relative": 0.321},
    "cluster_only": {"top_k": 2, "prior": 0.2, "crop_batch_size": 7, "edge_padding_scene": 0.1},
}

EXPECTED: dict[str, tuple[str, str]] = {
    "cluster_only": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/f2da2386789d5a70c6c23319615a2194.npz",
    ),
    "default": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/f2da2386789d5a70c6c23319615a2194.npz",
    ),
    "depth_source": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/476413d4ff694d99e38a727a9deefeb8.npz",
    ),
    "depth_tolerance": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/df5951ca9659a9de7c756bc70caafcf9.npz",
    ),
    "depth_tolerance_relative": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/1f5f795e97814c7fe348a13124f3eb2b.npz",
    ),
    "depth_tolerance_scene": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/5ca9ab7b2efee022577ce4ccc896d809.npz",
    ),
    "scene_scale": (
        "cache/perception/b82b3447eecc1e4f/be8aa0c9e9f4ce2921b61fa96973612f.npz",
        "cache/visibility/b82b3447eecc1e4f/cce82b186084d6da4ec297fd26df4957.npz",
    ),
}


@pytest.fixture(scope="module")
def scene() -> Scene:
    return load_scene(SAMPLE)


def keys(scene: Scene, params: PipelineParams) -> CacheKeys:
    return CacheKeys(
        lambda: scene,
        params,
        "pinned-models",
        "cache/",
        lengths=lambda: scene_lengths(params, scene.scale),
    )


@pytest.mark.parametrize("name", sorted(VARIATIONS))
def test_cache_keys_are_pinned(scene: Scene, name: str) -> None:
    k = keys(scene, PipelineParams(**VARIATIONS[name]))  # type: ignore[arg-type]
    assert (k.perception_key(1), k.visibility_key(1)) == EXPECTED[name]


ALIGNMENT_VARIATIONS: dict[str, dict[str, object]] = {
    "default": {},
    "scene_scale": {"scene_scale": 3.0},
    "alignment_min_score": {"alignment_min_score": 0.5},
    "alignment_frames": {"alignment_frames": 6},
    "cluster_only": {"top_k": 2, "prior": 0.2, "crop_batch_size": 7, "edge_padding_scene": 0.1},
}
ALIGNMENT_EXPECTED = {
    "alignment_frames": "802ef9ab99aad9d8",
    "alignment_min_score": "e943a4e55e48e8ee",
    "cluster_only": "1345e7ff27472d1c",
    "default": "1345e7ff27472d1c",
    "scene_scale": "7bdb0f3c60238f99",
}
"""The parameter part of the alignment verdict's key (`CacheKeys.alignment_key`), recorded on main
when the verdict became cached. Only that part is pinned: the whole key also hashes the check's
own source (`checks.alignment.code_fingerprint`), so an edit of that code misses it on purpose."""


@pytest.mark.parametrize("name", sorted(ALIGNMENT_VARIATIONS))
def test_alignment_key_parameters_are_pinned(name: str) -> None:
    params = PipelineParams(**ALIGNMENT_VARIATIONS[name])  # type: ignore[arg-type]
    assert short_hash(cache_parameters(ALIGNMENT_CACHE, params)) == ALIGNMENT_EXPECTED[name]
