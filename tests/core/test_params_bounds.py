"""Every numeric `PipelineParams` field has a lower and an upper bound.

Why: a job's parameters come from clients. An unbounded integer (a `crop_batch_size` of 10^18,
a `prefetch_frames` of 10^9) reaches an allocation or a thread pool before anything else can
refuse it. A new numeric field without bounds fails here unless it is listed in `UNBOUNDED`
with the reason it is safe.
"""

from __future__ import annotations

import types
import typing
from typing import Any

import annotated_types
import pytest
from pydantic import ValidationError

from bayesian_fields_core.params import PipelineParams

#: Numeric fields deliberately left without a bound on one side, and why. Empty today.
UNBOUNDED: dict[str, str] = {}


def _is_numeric(annotation: Any) -> bool:
    args = typing.get_args(annotation) if isinstance(annotation, types.UnionType) else ()
    kinds = set(args) - {type(None)} if args else {annotation}
    return bool(kinds) and kinds <= {int, float}


def _bounds(name: str) -> tuple[float | None, float | None]:
    low = high = None
    for item in PipelineParams.model_fields[name].metadata:
        if isinstance(item, annotated_types.Ge | annotated_types.Gt):
            low = item.ge if isinstance(item, annotated_types.Ge) else item.gt
        if isinstance(item, annotated_types.Le | annotated_types.Lt):
            high = item.le if isinstance(item, annotated_types.Le) else item.lt
    return low, high


NUMERIC = [n for n, f in PipelineParams.model_fields.items() if _is_numeric(f.annotation)]


def test_the_walk_finds_the_numeric_fields() -> None:
    assert {"crop_batch_size", "prefetch_frames", "top_k", "mu0", "depth_tolerance"} <= set(NUMERIC)
    assert "device" not in NUMERIC and "export_ply" not in NUMERIC


@pytest.mark.parametrize("name", NUMERIC)
def test_every_numeric_field_is_bounded_both_ways(name: str) -> None:
    if name in UNBOUNDED:
        pytest.skip(UNBOUNDED[name])
    low, high = _bounds(name)
    assert low is not None, f"{name} has no lower bound"
    assert high is not None, f"{name} has no upper bound"


@pytest.mark.parametrize("name", NUMERIC)
def test_values_past_the_bounds_are_refused_naming_the_field(name: str) -> None:
    low, high = _bounds(name)
    assert low is not None and high is not None
    integer = int in typing.get_args(PipelineParams.model_fields[name].annotation) or (
        PipelineParams.model_fields[name].annotation is int
    )
    for bad in (high + 1, low - 1, 10**18, 2**70, -(10**18)):
        value = int(bad) if integer else float(bad)
        with pytest.raises(ValidationError) as err:
            PipelineParams.model_validate({name: value})
        assert err.value.errors()[0]["loc"] == (name,)


@pytest.mark.parametrize(
    ("name", "value"),
    [("crop_batch_size", 10**18), ("crop_batch_size", 2**70), ("prefetch_frames", 10**9)],
)
def test_the_reported_values_are_refused(name: str, value: int) -> None:
    with pytest.raises(ValidationError, match="less than or equal"):
        PipelineParams.model_validate({name: value})
