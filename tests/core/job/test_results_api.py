"""The results API for people: a plain folder path reads a result; stage reports carry ISO times."""

from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.markers import read_marker
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results.reader import read_result
from tests.core.conftest import counting_models, make_job


@pytest.mark.slow
def test_read_result_takes_a_plain_path_and_reports_carry_iso_times(
    scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    job = make_job(scene_dir, tmp_path / "run", tmp_path / "cache", counting_models(profile))
    before = datetime.now().astimezone()
    run_job(job, force=True)
    out = tmp_path / "run" / "job"  # the job's folder, as `bfields run --out` makes it

    by_store = read_result(LocalStore(out), "result/")
    for source in (out, str(out), out / "result"):
        got = read_result(source)
        assert got.tasks == by_store.tasks and (got.object_ids == by_store.object_ids).all()
    with pytest.raises(InputError, match="no result here"):
        read_result(tmp_path / "cache")

    for stage in STAGES:
        report = read_marker(job.spec, stage)
        started = datetime.fromisoformat(report["started_at"])
        finished = datetime.fromisoformat(report["finished_at"])
        assert started.tzinfo is not None and before - timedelta(seconds=1) <= started <= finished
        assert (finished - started).total_seconds() == pytest.approx(report["seconds"], abs=0.01)


def _documented_layout() -> set[str]:
    """The paths of the "What lands where" block of the docs' getting-started page under
    `out/demo/` (numbers as NN...)."""
    text = (Path(__file__).resolve().parents[3] / "docs" / "getting-started.md").read_text()
    block = text[text.index("What lands where:") :].split("```")[1]
    paths, folder = set(), ""
    for line in block.splitlines():
        if line.startswith("~"):
            break
        token = line.strip().split(" ")[0] if line.strip() else ""
        indent = len(line) - len(line.lstrip())
        if not token or token == "out/demo/" or indent > 4:
            continue
        if indent == 2:
            folder = token if token.endswith("/") else ""
            if not token.endswith("/"):
                paths.add(token)
        else:
            paths.add(folder + token)
    return paths


@pytest.mark.slow
def test_docs_list_every_file_a_run_writes(scene_dir: Path, profile: dict, tmp_path: Path) -> None:
    import re

    job = make_job(scene_dir, tmp_path / "run", tmp_path / "cache", counting_models(profile))
    run_job(job, force=True)
    out = tmp_path / "run" / "job"
    written = {
        re.sub(r"object_\d+", "object_NNNNN", re.sub(r"task_\d+", "task_NN", str(p.relative_to(out))))
        for p in out.rglob("*")
        if p.is_file()
    }
    written = {re.sub(r"^stages/\w+\.json$", "stages/<stage>.json", p) for p in written}
    assert written - _documented_layout() == set()
