"""What `bfields run` hands on: output that survives a pipe, `--format tsv`, `--json` in the one
summary schema, the default output folder, and the run's configuration accepted back.

One real run in a fresh interpreter with stdout a pipe (as `bfields run ... | cat`), without
--out, in a scratch working folder; then `--config` re-runs of it in process (perception cached).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from bayesian_fields_core.cli.main import main
from bayesian_fields_core.cli.report import TSV_COLUMNS
from bayesian_fields_core.cli.run_config import CONFIG_FILE, read_run_config
from bayesian_fields_core.results.format import FORMAT_VERSION
from bayesian_fields_core.results.summary_schema import summary_schema

# Slow (the inner loop leaves it out): its fixtures took 60 s to set up here (--durations).
pytestmark = pytest.mark.slow

TASKS = ["red chair", "blue cup"]
CHEAP = ["--param", "alignment_check=false", "--param", "previews=false", "--param", "export_ply=false"]
CENTROID = re.compile(r"\([+-]\d+\.\d\d, [+-]\d+\.\d\d, [+-]\d+\.\d\d\)")


@pytest.fixture(scope="module")
def piped(scene_dir: Path, profile_yaml: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """`bfields run SCENE --task ... | cat` with no --out, in a fresh working folder, on a narrow
    terminal setting (COLUMNS=60: what rich would wrap the table to)."""
    work = tmp_path_factory.mktemp("piped")
    args = ["run", str(scene_dir), "--profile", str(profile_yaml), "--cache-dir", str(work / "cache"), "-q"]
    for task in TASKS:
        args += ["--task", task]
    done = subprocess.run(
        [sys.executable, "-m", "bayesian_fields_core.cli.main", *args, *CHEAP],
        cwd=work,
        env={**os.environ, "COLUMNS": "60"},
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return {"done": done, "work": work}


def _out_folder(piped: dict[str, Any]) -> Path:
    line = next(x for x in piped["done"].stderr.splitlines() if x.startswith("output folder: "))
    return piped["work"] / line.removeprefix("output folder: ")


def test_without_out_a_new_folder_under_outputs_is_made_and_printed(
    piped: dict[str, Any], scene_dir: Path
) -> None:
    out = _out_folder(piped)
    assert out.parent == piped["work"] / "outputs" / scene_dir.name
    assert re.fullmatch(r"\d{8}T\d{6}Z", out.name), out.name
    assert (out / "result" / "summary.json").is_file() and (out / CONFIG_FILE).is_file()


def test_a_piped_table_is_printed_at_its_natural_width(piped: dict[str, Any]) -> None:
    """No cell is wrapped: each answer is one row with its whole centroid, headers unbroken."""
    out = piped["done"].stdout
    summary = json.loads((_out_folder(piped) / "result" / "summary.json").read_text())
    answers = sum(len(s["objects"]) or 1 for s in summary["selections"])
    rows = [line for line in out.splitlines() if line.startswith("│")]
    assert len(rows) == answers, out
    assert all(CENTROID.search(row) for row in rows if "not found" not in row), out
    assert "p(relevant)" in out and "Gaussians" in out and max(map(len, out.splitlines())) > 60
    assert any("Gaussians," in line and "from cache" in line for line in out.splitlines()), out  # whole lines


def test_piped_messages_are_never_broken_at_the_console_width(
    piped: dict[str, Any], scene_dir: Path, profile_yaml: Path
) -> None:
    """stderr a pipe on a narrow setting (COLUMNS=60): the alignment line (longer than 60) arrives
    whole, as the table does on stdout; it used to break at rich's width ("... in the" / "camera
    frustums"). The run reuses the fixture's perception cache, with the alignment check on."""
    work = piped["work"]
    args = ["run", str(scene_dir), "--profile", str(profile_yaml), "--cache-dir", str(work / "cache")]
    args += ["--task", TASKS[0], "--out", str(work / "aligned"), "-q", *CHEAP[2:]]
    done = subprocess.run(
        [sys.executable, "-m", "bayesian_fields_core.cli.main", *args],
        env={**os.environ, "COLUMNS": "60"},
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stderr.splitlines() if x.startswith("alignment "))
    assert re.fullmatch(r"alignment ok: .*% of the splat in the camera frustums.*\(.+\)", line), done.stderr
    assert len(line) > 60


def test_the_configuration_has_what_decides_the_result(
    piped: dict[str, Any], scene_dir: Path, profile_yaml: Path
) -> None:
    config = read_run_config(_out_folder(piped) / CONFIG_FILE)
    assert config.scene.resolve() == scene_dir.resolve() and config.tasks == TASKS
    assert config.profile is not None and config.profile.resolve() == profile_yaml.resolve()
    assert config.parameters["alignment_check"] is False and "top_k" in config.parameters  # every one
    assert {"bayesian_fields", "python", "torch", "numpy"} <= set(config.versions)


def test_config_reruns_the_same_result_and_tsv_lists_it(
    piped: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first = _out_folder(piped)
    again = tmp_path / "again"
    cache = ["--cache-dir", str(piped["work"] / "cache")]
    assert (
        main(
            [
                "run",
                "--config",
                str(first / CONFIG_FILE),
                "--out",
                str(again),
                *cache,
                "-q",
                "--format",
                "tsv",
            ]
        )
        == 0
    )
    tsv = capsys.readouterr().out
    a = json.loads((first / "result" / "summary.json").read_text())
    b = json.loads((again / "result" / "summary.json").read_text())
    assert {k: v["sha256"] for k, v in a["arrays"].items()} == {
        k: v["sha256"] for k, v in b["arrays"].items()
    }
    assert a["selections"] == b["selections"] and a["parameters"] == b["parameters"]

    header, *rows = [line.split("\t") for line in tsv.splitlines()]
    assert tuple(header) == TSV_COLUMNS and all(len(r) == len(TSV_COLUMNS) for r in rows)
    expected = [
        (s["task"], str(rank), str(o["object_id"]), str(o["num_gaussians"]))
        for s in b["selections"]
        for rank, o in enumerate(s["objects"], start=1)
    ]
    assert [(r[0], r[1], r[2], r[5]) for r in rows if r[1]] == expected


def test_flags_beside_config_win(
    piped: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _out_folder(piped) / CONFIG_FILE
    cache = ["--cache-dir", str(piped["work"] / "cache")]
    args = ["run", "--config", str(config), "--out", str(tmp_path / "o"), *cache, "-q", "--json"]
    assert main([*args, "--task", "the mug", "--param", "top_k=1"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["tasks"] == ["the mug"] and printed["parameters"]["top_k"] == 1
    assert all(len(s["objects"]) <= 1 for s in printed["selections"])
    written = read_run_config(tmp_path / "o" / CONFIG_FILE)
    assert written.tasks == ["the mug"] and written.parameters["top_k"] == 1


def test_json_and_summary_json_validate_against_the_one_schema(
    piped: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _out_folder(piped) / CONFIG_FILE
    out = tmp_path / "j"
    cache = ["--cache-dir", str(piped["work"] / "cache")]
    assert main(["run", "--config", str(config), "--out", str(out), *cache, "-q", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    written = json.loads((out / "result" / "summary.json").read_text())
    schema = summary_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(written, schema, cls=jsonschema.Draft202012Validator)
    jsonschema.validate(printed, schema, cls=jsonschema.Draft202012Validator)
    assert {k: v for k, v in printed.items() if k != "run"} == written  # the same document
    assert Path(printed["run"]["result"]) == out / "result" and set(printed["run"]["stage_seconds"]) == {
        "perceive", "fuse", "cluster"
    }  # fmt: skip
    broken = {**written, "selections": [{"task": "x", "objects": [{"object_id": "seven"}]}]}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(broken, schema, cls=jsonschema.Draft202012Validator)


def test_the_schema_version_is_the_result_format_version() -> None:
    assert summary_schema()["schema_version"] == FORMAT_VERSION


def test_config_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "config.yaml"
    bad.write_text("tasks: [a]\n")
    assert main(["run", "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("bfields: error:") and "config.yaml" in err and "\n" not in err
    assert main(["run"]) == 2
    assert "--config" in capsys.readouterr().err
