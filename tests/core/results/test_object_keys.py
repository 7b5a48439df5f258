"""Object content keys and the comparison of two runs (issue 31, item 3), on hand-built id maps
where every expected key equality and every status is known exactly."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results import Result, read_result
from bayesian_fields_core.results.compare import compare_results, status_counts
from bayesian_fields_core.results.keys import object_key, object_keys, object_members
from bayesian_fields_core.results.writer import write_result


def _result(ids: list[int] | np.ndarray, digest: str = "splat-1") -> Result:
    ids = np.asarray(ids, dtype=np.int64)
    objects = int(ids.max()) + 1
    return Result(
        tasks=["t"],
        object_ids=ids,
        probabilities=np.full((objects, 2), 0.5, dtype=np.float32),
        selections={"t": []},
        splat_digest=digest,
    )


def test_members_are_each_objects_gaussians_in_increasing_order() -> None:
    ids = np.array([2, -1, 0, 2, 0, -1, 1, 2])
    members = object_members(ids, 4)
    assert [m.tolist() for m in members] == [[2, 4], [6], [0, 3, 7], []]


def test_keys_are_equal_exactly_when_the_gaussians_are() -> None:
    a = object_keys(np.array([0, 0, 1, 1, 2]), 3, "splat-1")
    # the same sets under other ids (rows permuted) and other Gaussians elsewhere
    b = object_keys(np.array([1, 1, 0, 0, -1]), 2, "splat-1")
    assert b == [a[1], a[0]]
    assert object_key(np.array([3, 1]), "s") == object_key(np.array([1, 3]), "s")  # order does not matter
    assert object_key(np.array([1, 3]), "s") != object_key(np.array([1, 2]), "s")
    assert object_key(np.array([1, 3]), "s") != object_key(np.array([1, 3]), "other splat")
    assert len(a[0]) == 16 and int(a[0], 16) >= 0


def test_keys_are_written_and_read_and_computed_for_results_without_them(tmp_path) -> None:
    result = _result([0, 0, 1, 1, 2, -1, 2])
    store = LocalStore(tmp_path)
    write_result(store, "r/", result)
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    expected = object_keys(result.object_ids, 3, "splat-1")
    assert summary["object_keys"] == expected and summary["splat_digest"] == "splat-1"
    assert read_result(store, "r/").content_keys() == expected
    # a result written before format 1.5: no keys, no digest; the reader computes them
    del summary["object_keys"], summary["splat_digest"]
    summary["format_version"] = "1.4"
    (tmp_path / "r" / "summary.json").write_text(json.dumps(summary))
    old = read_result(store, "r/")
    assert old.content_keys() == object_keys(result.object_ids, 3, "")


def test_compare_assigns_every_status_exactly() -> None:
    # run A: objects 0..5 over 30 Gaussians
    a = [0] * 4 + [1] * 6 + [2] * 3 + [3] * 3 + [4] * 5 + [5] * 4 + [-1] * 5
    b = list(a)
    b[:4] = [7] * 4  # A0 kept whole under another id: same
    b[4:10] = [1, 1, 1, 2, 2, 2]  # A1 divided in two halves... (each half is most of its B object)
    b[10:16] = [3] * 6  # A2 and A3 joined: merged
    b[16:21] = [4, 4, 4, 4, 9]  # A4 loses one Gaussian to a new object: changed
    b[21:25] = [-1] * 4  # A5 dropped entirely: gone
    b[25:30] = [5, 5, 6, 6, 9]  # unclustered Gaussians become objects 5, 6; object 9 takes one more
    rows = compare_results(_result(a), _result(b))
    by_b = {r.object_b: (r.status, r.objects_a, r.shared) for r in rows if r.object_b is not None}
    assert by_b == {
        7: ("same", [0], 4),
        1: ("split", [1], 3),
        2: ("split", [1], 3),
        3: ("merged", [2, 3], 6),
        4: ("changed", [4], 4),
        5: ("new", [], 0),
        6: ("new", [], 0),
        9: ("new", [], 0),  # one of its two Gaussians came from A4: no majority either way
    }
    assert [r.objects_a for r in rows if r.status == "gone"] == [[5]]
    assert status_counts(rows) == {"same": 1, "changed": 1, "split": 2, "merged": 1, "new": 3, "gone": 1}
    same = next(r for r in rows if r.status == "same")
    assert same.key_b == same.keys_a[0]  # same Gaussians of the same splat: the same key


def test_compare_refuses_runs_of_different_splats() -> None:
    with pytest.raises(InputError, match="different splats"):
        compare_results(_result([0, 1], "splat-1"), _result([0, 1], "splat-2"))
    with pytest.raises(InputError, match="not runs of one splat"):
        compare_results(_result([0, 1]), _result([0, 1, 1]))
