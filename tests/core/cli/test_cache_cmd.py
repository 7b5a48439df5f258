"""`bfields cache ls` and `bfields cache prune` on a cache filled by real runs of two profiles."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import pytest

from bayesian_fields_core.cli.cache_command import parse_duration, parse_size
from bayesian_fields_core.cli.cache_folder import VIEW_DIR
from bayesian_fields_core.cli.main import main
from bayesian_fields_core.job.artifacts import ALIGNMENT_CACHE_DIR
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.params import PipelineParams
from tests.core.conftest import N_FRAMES, TASKS, counting_models

# Slow (the inner loop leaves it out): its fixtures took 21 s to set up here (--durations).
pytestmark = pytest.mark.slow


def _other(profile: dict[str, Any]) -> dict[str, Any]:
    params = {**profile["segmenter"]["params"], "min_size": 30}
    return dict(profile, name="other-profile", segmenter={"kind": "classical", "params": params})


def _run(scene: Path, out: Path, cache: Path, profile: dict[str, Any]) -> dict:
    job = local_job(scene, out, cache, list(TASKS), PipelineParams(), counting_models(profile))
    return run_job(job, force=True)


@pytest.fixture(scope="module")
def two_profiles(scene_dir: Path, profile: dict, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache holding the scene under the test profile and under another one."""
    root = tmp_path_factory.mktemp("cache-cmd")
    _run(scene_dir, root / "out1", root / "cache", profile)
    _run(scene_dir, root / "out2", root / "cache", _other(profile))
    return root / "cache"


def _download(cache: Path, job: str, run: Path, age_s: float) -> Path:
    """What `bfields view --job JOB` leaves: the job's result under view/JOB/ (here a real run's
    result folder), last viewed `age_s` ago."""
    target = cache / VIEW_DIR / job
    shutil.copytree(run / "result", target / "result")
    then = time.time() - age_s
    for path in target.rglob("*"):
        os.utime(path, (then, then))
    return target


def _files_bytes(folder: Path) -> int:
    """What a disk holds in `folder`: the sum of its regular files' sizes (du --apparent-size)."""
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


@pytest.fixture
def cache(two_profiles: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "cache"
    shutil.copytree(two_profiles, copy)
    return copy


def _ls_all(cache: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    assert main(["cache", "ls", "--cache-dir", str(cache), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _ls(cache: Path, capsys: pytest.CaptureFixture[str]) -> list[dict]:
    return _ls_all(cache, capsys)["entries"]


def _age(cache: Path, profile_name: str, seconds: float) -> None:
    """Make one entry look last used `seconds` ago (as if its runs were that long ago)."""
    for path in (cache / "index").glob("*.json"):
        doc = json.loads(path.read_text())
        if doc["profile"] == profile_name:
            doc["last_used"] = time.time() - seconds
            path.write_text(json.dumps(doc))


def _npz(cache: Path) -> int:
    return len(list(cache.rglob("*.npz")))


def test_ls_lists_each_scene_and_profile_with_size(
    cache: Path, scene_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    entries = _ls(cache, capsys)
    assert sorted(e["profile"] for e in entries) == ["other-profile", "pipeline-test"]
    assert len({e["scene_id"] for e in entries}) == 1  # one scene (by content), two profiles
    assert len({e["fingerprint"] for e in entries}) == 2
    for e in entries:
        assert e["scene"] == str(scene_dir.resolve())
        assert e["frames"] == N_FRAMES
        assert e["files"] == 2 * N_FRAMES + 1  # perception + visibility per frame, the alignment verdict
        assert e["bytes"] > 0 and 0 <= e["last_used_s_ago"] < 600
    # the verdict does not depend on the models: both profiles' entries reference the one file
    [verdict] = (cache / ALIGNMENT_CACHE_DIR).iterdir()
    on_disk = sum(p.stat().st_size for p in cache.rglob("*.npz")) + 2 * verdict.stat().st_size
    assert sum(e["bytes"] for e in entries) == on_disk

    assert main(["cache", "ls", "--cache-dir", str(cache)]) == 0
    text = capsys.readouterr().out
    assert "2 entries" in text and "pipeline-test" in text and "other-profile" in text


def test_prune_older_than_drops_only_stale_entries(
    cache: Path, scene_dir: Path, profile: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _age(cache, "other-profile", 3 * 86400)
    assert main(["cache", "prune", "--older-than", "2d", "--cache-dir", str(cache)]) == 0
    assert "removed 1 entries" in capsys.readouterr().out
    assert [e["profile"] for e in _ls(cache, capsys)] == ["pipeline-test"]
    assert _npz(cache) == 2 * N_FRAMES
    # The kept profile still runs from the cache; the pruned one computes again.
    assert _run(scene_dir, tmp_path / "o1", cache, profile)["perceive"]["frames_computed"] == 0
    assert _run(scene_dir, tmp_path / "o2", cache, _other(profile))["perceive"]["frames_computed"] == N_FRAMES


def test_prune_max_size_drops_least_recently_used_first(
    cache: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _age(cache, "pipeline-test", 3600)  # used before the other one
    sizes = {e["profile"]: e["bytes"] for e in _ls(cache, capsys)}
    budget = sizes["other-profile"] + 1
    assert main(["cache", "prune", "--max-size", str(budget), "--cache-dir", str(cache)]) == 0
    capsys.readouterr()
    assert [e["profile"] for e in _ls(cache, capsys)] == ["other-profile"]
    assert sum(p.stat().st_size for p in cache.rglob("*.npz")) <= budget

    assert main(["cache", "prune", "--max-size", "0", "--cache-dir", str(cache)]) == 0
    assert "removed 1 entries" in capsys.readouterr().out
    assert _ls(cache, capsys) == [] and _npz(cache) == 0


def test_prune_removes_unreferenced_files(cache: Path, capsys: pytest.CaptureFixture[str]) -> None:
    legacy = cache / "scenes" / "0123456789abcdef" / "cache" / "ffff" / "perception" / "frame_00000.npz"
    legacy.parent.mkdir(parents=True)
    legacy.write_bytes(b"x" * 100)  # what the path-keyed layout left behind
    before = _npz(cache)
    assert main(["cache", "prune", "--older-than", "30d", "--cache-dir", str(cache)]) == 0
    assert "removed 0 entries and 1 files" in capsys.readouterr().out
    assert not legacy.exists() and _npz(cache) == before - 1


def test_ls_counts_every_file_on_disk_view_downloads_included(
    cache: Path, two_profiles: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It reported the frames alone (987 KiB of a 16 MB folder): `view --job` downloads were missed."""
    run = two_profiles.parent / "out1"
    _download(cache, "job-old", run, 3 * 86400)
    _download(cache, "job-new", run, 60)
    listing = _ls_all(cache, capsys)
    assert listing["bytes_on_disk"] == _files_bytes(cache)
    views = listing["view_downloads"]
    assert [v["job"] for v in views] == ["job-new", "job-old"]  # most recently viewed first
    assert all(v["bytes"] == _files_bytes(run / "result") > 0 for v in views)

    assert main(["cache", "ls", "--cache-dir", str(cache)]) == 0
    text = capsys.readouterr().out
    assert "2 entries, 2 view downloads" in text and "job-new" in text and "job-old" in text


def test_prune_removes_view_downloads_by_age_and_first_by_size(
    cache: Path, two_profiles: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = two_profiles.parent / "out1"
    old = _download(cache, "job-old", run, 3 * 86400)
    new = _download(cache, "job-new", run, 60)
    assert main(["cache", "prune", "--older-than", "2d", "--cache-dir", str(cache)]) == 0
    said = capsys.readouterr().out
    assert "removed 0 entries" in said and "1 view downloads" in said, said
    assert not old.exists() and new.exists() and len(_ls(cache, capsys)) == 2

    # --max-size counts the downloads too, and drops them before any entry (frames cost
    # perception again; a view downloads its result again).
    frames = _ls_all(cache, capsys)["bytes_on_disk"] - _files_bytes(new)
    assert main(["cache", "prune", "--max-size", str(frames), "--cache-dir", str(cache)]) == 0
    said = capsys.readouterr().out
    assert "removed 0 entries" in said and "1 view downloads" in said, said
    assert not new.exists() and len(_ls(cache, capsys)) == 2
    assert _ls_all(cache, capsys)["bytes_on_disk"] == _files_bytes(cache) == frames


def test_prune_needs_a_limit_and_parses_them(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["cache", "prune", "--cache-dir", str(tmp_path)]) == 2
    assert "--older-than" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["cache", "prune", "--older-than", "soon", "--cache-dir", str(tmp_path)])
    assert exc.value.code == 2
    assert "expected a duration" in capsys.readouterr().err
    assert (
        parse_duration("90") == 90
        and parse_duration("12h") == 12 * 3600
        and parse_duration("2w") == 14 * 86400
    )
    assert parse_size("500M") == 500 << 20 and parse_size("1.5GB") == 3 << 29 and parse_size("4096") == 4096
    with pytest.raises(Exception, match="expected a size"):
        parse_size("lots")
