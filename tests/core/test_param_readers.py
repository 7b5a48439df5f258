"""Each parameter says, in its own annotation, which stage reads it; the rest derives from that.

The `ReadBy` marker beside every `PipelineParams` field is the one place that answers "who reads
this and does it key a cache": the stage table's cache specs, `bfields params` and the docs'
table read it, and the length parameters are read only where `scene_lengths` resolves them.
"""

from __future__ import annotations

import ast
import typing
from pathlib import Path

import pytest

import bayesian_fields_core.params as params_module
from bayesian_fields_core.cli import params_table
from bayesian_fields_core.job.stage_table import (
    ALIGNMENT_CACHE,
    CACHES,
    PERCEPTION_CACHE,
    STAGES,
    VISIBILITY_CACHE,
)
from bayesian_fields_core.params import (
    CacheName,
    PipelineParams,
    keyed_parameters,
    length_parameters,
    read_by,
    readers,
)

ROOT = Path(__file__).resolve().parents[2]
LENGTH_RESOLVER = ROOT / "bayesian_fields_core" / "scene" / "scale.py"


def test_every_parameter_names_exactly_one_reader() -> None:
    found = readers()
    assert list(found) == list(PipelineParams.model_fields)
    assert {stage for r in found.values() for stage in r.stages} <= {"job", *STAGES}
    assert all(r.stage not in r.also and "job" not in r.also for r in found.values())
    assert all(r.why for r in found.values())


def test_a_field_without_a_marker_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    class Unmarked(PipelineParams):
        extra_knob: int = 3

    monkeypatch.setattr(params_module, "PipelineParams", Unmarked)
    with pytest.raises(TypeError, match="extra_knob must carry exactly one ReadBy marker, has 0"):
        read_by("extra_knob")
    with pytest.raises(KeyError, match="no field 'nope'"):
        read_by("nope")


def test_the_cache_specs_are_the_keyed_markers() -> None:
    """A cache's key hashes exactly the parameters whose markers name it, and every name a marker
    uses is a cache (a misspelt one would key nothing)."""
    by_name = {spec.folder.rstrip("/"): spec for spec in CACHES}
    assert set(by_name) == set(typing.get_args(CacheName))
    for name, spec in by_name.items():
        assert spec.params == keyed_parameters(name)  # type: ignore[arg-type]
    # The perception key hashes no parameters (CacheKeys.perception_digest): naming it in a marker
    # needs that digest taught first, or the mark would promise a miss that never happens.
    assert PERCEPTION_CACHE.params == ()
    assert VISIBILITY_CACHE.params == (
        "depth_source",
        "scene_scale",
        "depth_tolerance",
        "depth_tolerance_scene",
        "depth_tolerance_relative",
    )
    assert ALIGNMENT_CACHE.params == (
        "alignment_min_frustum_share",
        "alignment_max_extent_ratio",
        "alignment_min_score",
        "alignment_frames",
        "alignment_max_side",
        "scene_scale",
    )


def test_the_table_shows_each_reader() -> None:
    rows = {r.name: r for r in params_table.rows()}
    assert rows["depth_tolerance_scene"].read_by == "fuse: visibility; keys the visibility cache"
    assert rows["scene_scale"].read_by == "fuse: visibility; keys the visibility and alignment cache"
    assert rows["top_k"].read_by == "cluster: objects"
    assert rows["prior"].read_by == "fuse, cluster: fusion update"  # the per-view conditionals read it too
    assert "| read by |" in params_table.markdown_table().splitlines()[0]


def _raw_length_reads(path: Path, names: set[str]) -> list[str]:
    """`params.<length>` / `p.<length>` / `<x>.params.<length>` reads, and any `<x>.<name>_scene`
    (only the parameters carry that suffix): lengths read around `SceneLengths`."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if not (isinstance(node, ast.Attribute) and node.attr in names):
            continue
        base = ast.unparse(node.value)
        if base in ("params", "p") or base.endswith(".params") or node.attr.endswith("_scene"):
            found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {base}.{node.attr}")
    return found


def test_lengths_are_read_only_through_the_scene_lengths() -> None:
    """The bug of e83888d: a caller read `depth_tolerance` raw (None once lengths became
    relative) instead of the run's resolved lengths. Only `scene_lengths` reads them now."""
    names = set(length_parameters())
    assert names == {
        "scene_scale",
        "depth_tolerance",
        "depth_tolerance_scene",
        "edge_padding",
        "edge_padding_scene",
    }
    found = [
        line
        for folder in ("bayesian_fields_core", "services", "bench", "scripts")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path != LENGTH_RESOLVER
        for line in _raw_length_reads(path, names)
    ]
    assert found == [], "read these from SceneLengths (scene.lengths):\n" + "\n".join(found)
    # the walk does see a raw read where there is one
    assert _raw_length_reads(LENGTH_RESOLVER, names)
