"""The `ReadBy` markers checked against what the stages do, not against what they say.

tests/core/test_param_readers.py checks that the markers and everything derived from them agree;
it cannot see a stage reading a field its marker does not name (`prior` was marked `fuse` while
the cluster stage's per-view conditionals read it too). Here the stages run on the tiny scene with
a `PipelineParams` that records every field read and the stage it happened in, and:

- every stage seen reading a field is one its marker names (`stage` or `also`; "job" fields are
  read through the job by any stage, lengths resolved once by whichever stage first needs one);
- changing a field to another valid value moves exactly the cache keys its marker names (the
  keys as `CacheKeys` computes them): a field a cache's content depends on must miss that cache,
  and one that keys no cache (the fusion update's `mu0`, the cluster stage's `top_k`: their
  results are job artifacts, recomputed each job) must not throw a cache away.
"""

from __future__ import annotations

import typing
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest

from bayesian_fields_core.job.cache_keys import CacheKeys
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_core.params import PipelineParams, readers
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.scale import scene_lengths
from tests.core.conftest import counting_models, make_job

# Slow (the inner loop leaves it out): it runs the three stages on the tiny scene (~5 s of fixtures).
pytestmark = pytest.mark.slow

FIELDS = frozenset(PipelineParams.model_fields)
_current: list[str] = []  # the stage running now (a list: the recorder reads it from any thread)
_reads: dict[str, set[str]] = defaultdict(set)  # field -> stages seen reading it


class RecordingParams(PipelineParams):
    """`PipelineParams` that notes, for every field read while a stage runs, that stage."""

    def __getattribute__(self, name: str) -> Any:
        if name in FIELDS and _current:
            _reads[name].add(_current[-1])
        return super().__getattribute__(name)


def _observed_readers(scene_dir: Path, profile: dict[str, Any], root: Path) -> dict[str, set[str]]:
    _reads.clear()
    job = make_job(
        scene_dir, root / "job", root / "cache", counting_models(profile), params=RecordingParams()
    )
    for name in STAGES:
        _current.append(name)
        try:
            run_stage(name, job)
        finally:
            _current.pop()
    return dict(_reads)


def test_every_stage_that_reads_a_field_is_named_by_its_marker(
    scene_dir: Path, profile: dict[str, Any], tmp_path: Path
) -> None:
    seen = _observed_readers(scene_dir, profile, tmp_path)
    # the recorder sees reads in every stage (a recorder that saw nothing would pass anything)
    assert {stage for stages in seen.values() for stage in stages} == set(STAGES)
    assert "cluster" in seen["top_k"] and "fuse" in seen["mu0"]
    markers = readers()
    unmarked = {
        name: sorted(stages - set(markers[name].stages))
        for name, stages in seen.items()
        # "job" fields are read through the job by every stage; lengths are resolved all at once
        # (`JobScene.lengths`) by whichever stage first needs one, and read as `SceneLengths`
        if markers[name].stage != "job"
        and not markers[name].length
        and not stages <= set(markers[name].stages)
    }
    assert unmarked == {}, (
        f"stages read these fields without their ReadBy naming them (add `also=`): {unmarked}"
    )
    assert seen["prior"] == {"fuse", "cluster"}  # the per-view conditionals (default) read it


def _other_value(name: str) -> Any:
    """A valid value of field `name` other than its default (ValueError when none of the
    candidates is one: the test must then be taught the field)."""
    field = PipelineParams.model_fields[name]
    default = field.default
    options: list[Any] = []
    for arg in typing.get_args(field.annotation):  # Literal options, also inside a union
        options += [a for a in (arg, *typing.get_args(arg)) if isinstance(a, str)]
    if isinstance(default, bool):
        options.append(not default)
    if isinstance(default, int | float) and not isinstance(default, bool):
        options += [default + 1, default * 0.5, default * 1.1, default - 1]
    options += [0.5, 0.01, 2, 1, "cpu"]
    for value in options:
        if value == default:
            continue
        try:
            changed = PipelineParams(**{name: value})
        except ValueError:
            continue
        if getattr(changed, name) != default:
            return value
    raise ValueError(f"no other valid value found for {name}; add a candidate to _other_value")


def _keys(scene: Any, params: PipelineParams) -> dict[str, str]:
    keys = CacheKeys(
        lambda: scene,
        params,
        "models",
        "cache/",
        lengths=lambda: scene_lengths(params, scene.scale),
    )
    return {
        "perception": keys.perception_key(0),
        "visibility": keys.visibility_key(0),
        "alignment": keys.alignment_key(),
    }


def test_a_field_moves_exactly_the_cache_keys_its_marker_names(scene_dir: Path) -> None:
    scene = load_scene(scene_dir)
    base = _keys(scene, PipelineParams())
    wrong = {}
    for name, marker in readers().items():
        changed = _keys(scene, PipelineParams(**{name: _other_value(name)}))
        moved = {cache for cache in base if base[cache] != changed[cache]}
        if moved != set(marker.keys):
            wrong[name] = (sorted(moved), sorted(marker.keys))
    assert wrong == {}, f"field: (caches its change moves, caches its ReadBy keys): {wrong}"
