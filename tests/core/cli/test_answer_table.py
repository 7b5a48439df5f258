"""The CLI's answer table: ranks follow the number it shows, and lengths say which units they are in.

The demo used to rank by evidence while showing p(relevant) (rank 1 p 0.959 above rank 2 p 1.000)
under a 'centroid (m)' header, for COLMAP scenes whose units are arbitrary."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.cli.report import print_result
from bayesian_fields_core.geometry.obb import OrientedBox
from bayesian_fields_core.results.format import Result, SelectedObject

TASKS = ["get the cyan cube", "get the orange cone"]


def _object(object_id: int, p: float, score: float) -> SelectedObject:
    box = OrientedBox(np.zeros(3), np.eye(3), np.ones(3))
    return SelectedObject(object_id, p, 100, np.array([0.1, 0.2, 0.3]), box, score=score)


def _result(units: str) -> Result:
    """Evidence ranks 0 before 1 although 1's p is higher (it saturated on fewer views)."""
    return Result(
        tasks=TASKS,
        object_ids=np.array([0, 1, 2, -1]),
        probabilities=np.full((3, 3), 1 / 3, dtype=np.float32),
        selections={
            TASKS[0]: [_object(0, 0.959, 14.2), _object(1, 1.0, 9.7)],
            TASKS[1]: [_object(2, 0.8, 3.1)],
        },
        parameters={"prune_threshold": 0.1, "selection_score": "evidence"},
        scene_scale={
            "value": 1.849,
            "source": "derived",
            "units": units,
            "lengths": {"depth_tolerance": 0.05},
        },
        ranked_by="evidence",
    )


def _table(capsys: pytest.CaptureFixture[str], result: Result, tmp_path: Path) -> str:
    print_result(result, {}, tmp_path)
    return capsys.readouterr().out


def test_the_ranks_follow_the_shown_score_and_the_caption_says_which(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    out = _table(capsys, _result("scene units"), tmp_path)
    assert "evidence (ranks)" in out and "Ranked by evidence" in out
    assert "centroid (scene units)" in out and "centroid (m)" not in out
    assert "p(relevant) < 0.1 for a task are not its answers" in out
    first_task = out[out.index(TASKS[0]) : out.index(TASKS[1])]
    shown = [float(s) for s in re.findall(r"[+-]\d+\.\d\d(?= )", first_task)][:2]
    assert shown == [14.2, 9.7]  # the ranked column, best first
    assert "scene scale 1.849 scene units" in out


def test_metres_only_for_a_declared_metric_capture(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    assert "centroid (m)" in _table(capsys, _result("m"), tmp_path)


def test_json_gives_the_ranking_score(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from bayesian_fields_core.job.store import LocalStore
    from bayesian_fields_core.results.writer import write_result

    write_result(LocalStore(tmp_path), "result/", _result("scene units"))
    print_result(_result("scene units"), {}, tmp_path, output_format="json")
    summary = json.loads(capsys.readouterr().out)
    assert summary["ranked_by"] == "evidence"
    assert [o["score"] for o in summary["selections"][0]["objects"]] == [14.2, 9.7]
    assert summary["scene_scale"]["units"] == "scene units"
