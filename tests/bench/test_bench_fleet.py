"""The pure parts of `bench/bench_fleet.py` (its numbers are only as good as these): Jain's index,
percentiles, queue waits, the backlog window, worker-time shares, perception runs and crash counts
from job records. No stack is started; the bench itself is run by hand."""

from __future__ import annotations

import json

import pytest

from bench.bench_fleet import (
    artifact_digest,
    backlog_window,
    compare_digests,
    crash_effects,
    jain_index,
    percentile,
    perception_runs,
    queue_waits,
    starts_in,
    throughput_per_min,
    worker_seconds,
)


def _rec(
    job: str, tenant: str, created: int, started: int | None, finished: int | None, **kw: object
) -> dict:
    def at(s: int | None) -> str | None:
        return None if s is None else f"2025-01-01T00:{s // 60:02d}:{s % 60:02d}+00:00"

    return {"id": job, "tenant": tenant, "scene_id": "s1", "state": kw.pop("state", "succeeded"),
            "created_at": at(created), "started_at": at(started), "finished_at": at(finished),
            "stage_runs": kw.pop("stage_runs", 3), "timings": kw.pop("timings", {}), **kw}  # fmt: skip


def test_jain_index_bounds() -> None:
    assert jain_index([5.0, 5.0]) == pytest.approx(1.0)
    assert jain_index([10.0, 0.0]) == pytest.approx(0.5)  # one of two takes all: 1/n
    assert jain_index([3.0, 1.0]) == pytest.approx(16 / 20)
    assert jain_index([0.0, 0.0]) is None


def test_percentile_interpolates_and_handles_empty() -> None:
    assert percentile([1, 2, 3, 4], 50) == pytest.approx(2.5)
    assert percentile(list(range(101)), 99) == pytest.approx(99.0)
    assert percentile([], 99) is None


def test_waits_window_and_shares_from_records() -> None:
    records = [
        _rec("a1", "tenant-a", 0, 2, 12, timings={"perceive": 6, "fuse": 2, "cluster": 2}),
        _rec("a2", "tenant-a", 0, 20, 30, timings={"perceive": 10}),
        _rec("b1", "tenant-b", 5, 12, 22, timings={"perceive": 5}),
        _rec("c1", "tenant-c", 8, None, None, state="queued"),
    ]
    waits = queue_waits(records)
    assert waits == {"tenant-a": [2.0, 20.0], "tenant-b": [7.0]}  # C never started: no wait
    t0 = records[0]["created_at"]
    from bench.bench_fleet import epoch

    base = epoch(t0)
    assert base is not None
    window = backlog_window(records, ("tenant-a", "tenant-b"))
    assert window == (base + 5, base + 12)  # B joined at 5; B's last job started at 12
    # a1 ran 2..12 with 10 stage-seconds: 7 of its 10 seconds fall in 5..12
    assert worker_seconds(records, "tenant-a", window) == pytest.approx(7.0)
    assert worker_seconds(records, "tenant-b", window) == pytest.approx(0.0)
    assert starts_in(records, "tenant-a", window) == 0 and starts_in(records, "tenant-b", window) == 1
    assert backlog_window(records, ("tenant-a", "tenant-c")) is None
    assert throughput_per_min(records) == pytest.approx(60 * 3 / 30)


def test_perception_runs_crash_effects_and_digests() -> None:
    records = [
        _rec(
            "j1", "tenant-a", 0, 1, 5, stage_reports={"perceive": {"frames_computed": 4, "encoder_calls": 2}}
        ),
        _rec(
            "j2",
            "tenant-a",
            0,
            1,
            6,
            stage_reports={"perceive": {"frames_computed": 0, "encoder_calls": 0}},
            stage_runs=4,
        ),  # fmt: skip
        _rec("j3", "tenant-a", 0, 1, None, state="running"),
    ]
    assert perception_runs(records, {"s1": "a0"}) == {"a0": {"jobs": 3, "runs": 1, "encoder_calls": 2}}
    effects = crash_effects(["j1", "j2", "j3", "j4"], records + [records[0]])
    assert effects["lost"] == {"j3": "running (stage_runs 3)", "j4": "not listed"}
    assert effects["listed_twice"] == ["j1"]
    assert effects["ran_a_stage_twice"] == [{"id": "j2", "stage_runs": 4}]
    same = compare_digests(
        {"k1": {"a.npz": "x"}, "k2": {"a.npz": "y", "b.png": "z"}, "k3": {"a.npz": "z"}},
        {"k1": {"a.npz": "x"}, "k2": {"a.npz": "y", "b.png": "other"}},
    )
    assert same == {"compared": 2, "identical": 1, "differ": ["k2"], "paths": ["b.png"]}

    def summary(seconds: float, scene_id: str, objects: int = 3) -> bytes:
        scene = {"store_prefix": f"scenes/{scene_id}/input/", "num_frames": 4}
        return json.dumps({"objects": objects, "timings_s": {"aib": seconds}, "scene": scene}).encode()

    digest = artifact_digest("result/summary.json", summary(0.5, "s_1"))
    assert digest == artifact_digest("result/summary.json", summary(0.7, "s_2"))
    assert digest != artifact_digest("result/summary.json", summary(0.5, "s_1", objects=4))
    timed = summary(0.5, "s_1")
    assert artifact_digest("result/x.json", timed) != artifact_digest("result/x.json", timed + b" ")
