"""What the CLI accepts and how it refuses: every parameter in `run --help` and `params`, the
nearest names for a typo, and one-line errors (never tracebacks) for input problems."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bayesian_fields_core.cli import params_table
from bayesian_fields_core.cli.main import build_parser, main
from bayesian_fields_core.job.markers import is_done
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.stage_table import STAGES
from bayesian_fields_core.params import PipelineParams
from tests.core.conftest import counting_models, make_job

from .test_cli import _one_line_error, _run_args


def _help(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 0
    return capsys.readouterr().out


def test_run_help_lists_every_parameter_with_type_and_default(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(["run", "--help"], capsys)
    for row in params_table.rows():
        assert f"{row.name}  ({row.type}, default {row.default}; read by {row.read_by})" in text
    assert "Absolute visibility tolerance" in text  # the descriptions come along


def test_params_prints_the_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params"]) == 0
    text = capsys.readouterr().out
    assert all(name in text for name in PipelineParams.model_fields)
    assert main(["params", "--markdown"]) == 0
    assert capsys.readouterr().out == params_table.markdown_table()
    assert main(["params", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == list(PipelineParams.model_fields)
    defaults = {r["name"]: r["default"] for r in rows}
    assert defaults["depth_tolerance"] == "null"  # relative by default: a fraction of the scene scale
    assert defaults["depth_tolerance_scene"] == "0.02704166"


def test_generate_help_shows_the_generator_options(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(["generate", "--help"], capsys)
    assert "--n-objects" in text or "--num-objects" in text or "--suite" in text
    assert "--device" in text


def test_generate_help_lists_seed_once_and_seed_reaches_the_generator(tmp_path: Path) -> None:
    """`bfields generate --help` in a real interpreter: --seed once (the generator's); it showed
    the wrapper's --seed and the generator's. A seed given before OUT still reaches the scene."""
    done = subprocess.run(
        [sys.executable, "-m", "bayesian_fields_core.cli.main", "generate", "--help"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert re.findall(r"--seed\b", done.stdout) == ["--seed"], done.stdout
    args = build_parser().parse_args(["generate", "--seed", "7", str(tmp_path / "s"), "--n-frames", "4"])
    assert args.seed == 7 and args.extra == ["--n-frames", "4"]
    assert build_parser().parse_args(["generate", str(tmp_path / "s")]).seed is None  # the spec's default


@pytest.mark.parametrize(
    ("flag", "near"),
    [("depth_tolerence=0.1", "depth_tolerance"), ("topk=3", "top_k"), ("knn_std=1", "knn_std_ratio")],
)
def test_an_unknown_param_suggests_the_nearest_names(
    flag: str,
    near: str,
    scene_dir: Path,
    profile_yaml: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(_run_args(scene_dir, tmp_path, profile_yaml, "--task", "a cup", "--param", flag)) == 2
    err = _one_line_error(capsys)
    assert "unknown parameter" in err and "did you mean" in err and near in err


def test_an_unknown_name_in_a_params_file_is_refused_alike(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("prune_treshold: 0.2\n")
    assert main(_run_args(scene_dir, tmp_path, profile_yaml, "--task", "a cup", "--params", str(params))) == 2
    assert "did you mean prune_threshold" in _one_line_error(capsys)


def test_a_cuda_device_this_machine_lacks_is_one_line(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # cuda:99: no machine has a hundred GPUs, so this refuses everywhere (with or without CUDA)
    assert (
        main(_run_args(scene_dir, tmp_path, profile_yaml, "--task", "a cup", "--param", "device=cuda:99"))
        == 2
    )
    assert "device 'cuda:99' asked for, but torch finds" in _one_line_error(capsys)


def test_tasks_given_a_folder_is_one_line(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_run_args(scene_dir, tmp_path, profile_yaml, "--tasks", str(tmp_path))) == 2
    assert "is a folder; expected a tasks file" in _one_line_error(capsys)


def test_input_depth_without_depth_maps_is_refused_before_perception(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = _run_args(scene_dir, tmp_path, profile_yaml, "--task", "a cup", "--param", "depth_source=input")
    assert main(args) == 2
    assert "depth_source='input' but" in _one_line_error(capsys)
    assert not (tmp_path / "out" / "stages").exists()  # no stage ran


@pytest.mark.slow
def test_a_failed_rerun_leaves_no_marker_of_the_run_before(
    scene_dir: Path, profile: dict, tmp_path: Path
) -> None:
    """`run_job(force=True)` over a finished job that fails in its second stage: the first
    run's later markers must not survive to say the job is done."""
    job = make_job(scene_dir, tmp_path / "job", tmp_path / "cache", counting_models(profile))
    run_job(job, force=True)
    assert all(is_done(job.spec, s) for s in STAGES)

    in_fuse: list[str] = []  # the cancel flag is raised once fuse has reported progress

    def note_stage(stage: str, _fraction: float) -> None:
        if stage == "fuse":
            in_fuse.append(stage)

    rerun = make_job(
        scene_dir,
        tmp_path / "job",
        tmp_path / "cache",
        counting_models(profile),
        progress=note_stage,
        should_cancel=lambda: bool(in_fuse),
    )
    with pytest.raises(Exception, match="cancelled"):
        run_job(rerun, force=True)
    assert is_done(rerun.spec, "perceive")
    assert not is_done(rerun.spec, "fuse") and not is_done(rerun.spec, "cluster")
