"""`bfields run` and `bfields calibrate` through `cli.main`: output on success, and a one-line
message with exit status 2 (never a traceback) on each kind of bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from PIL import Image

from bayesian_fields_core.calibration.model import load_calibration
from bayesian_fields_core.cli.main import main
from tests.core.conftest import N_FRAMES
from tests.support.scene_transforms import copy_scene, flip_camera_convention, move_splat


def _run_args(scene: Path, tmp_path: Path, profile_yaml: Path, *extra: str) -> list[str]:
    return [
        "run",
        str(scene),
        "--out",
        str(tmp_path / "out"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--profile",
        str(profile_yaml),
        "-q",
        *extra,
    ]


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("bfields: error:"), err
    assert "\n" not in err and "Traceback" not in err, err
    return err


@pytest.mark.slow
def test_run_prints_objects_per_task(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tasks = ["red chair", "blue cup"]
    args = _run_args(scene_dir, tmp_path, profile_yaml, "--task", tasks[0], "--task", tasks[1])
    assert main([*args, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["tasks"] == tasks and [s["task"] for s in summary["selections"]] == tasks
    assert any(s["objects"] for s in summary["selections"])
    root = Path(summary["run"]["result"])
    assert root == tmp_path / "out" / "result" and (root / "summary.json").is_file()
    for selection in summary["selections"]:
        for obj in selection["objects"]:
            assert obj["num_gaussians"] > 0 and 0.0 <= obj["probability"] <= 1.0
            assert len(obj["box"]["extents"]) == 3 and (root / obj["export"]).is_file()
    previews = summary["previews"]
    assert (root / previews["contact_sheet"]).is_file() and [p["task"] for p in previews["tasks"]] == tasks
    assert all((root / p["file"]).is_file() for p in previews["tasks"])
    assert all((root / summary["exports"]["tasks"][t]).is_file() for t in tasks)

    # The human table, on a second run of the same scene: perception comes from the cache.
    assert main(args) == 0
    text = capsys.readouterr().out
    assert all(task in text for task in tasks)
    assert f"{N_FRAMES} from cache" in text


@pytest.mark.slow
def test_run_reads_a_tasks_file(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tasks_file = tmp_path / "tasks.txt"
    tasks_file.write_text("# one per line\nthe mug\nred chair\n")
    assert main([*_run_args(scene_dir, tmp_path, profile_yaml, "--tasks", str(tasks_file)), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["tasks"] == ["the mug", "red chair"]


BAD_TASK_FILES = {
    "malformed.yaml": ("tasks: [unclosed\n", "cannot parse"),
    "mapping.yaml": ("color: red\n", "expected a list"),
    "empty.yaml": ("[]\n", "empty"),
    "empty.txt": ("\n# nothing\n", "empty"),
    "duplicates.json": ('["cup", "cup"]', "duplicate"),
    "broken.json": ('["cup", ', "cannot parse"),
}


@pytest.mark.parametrize("name", sorted(BAD_TASK_FILES))
def test_run_rejects_bad_task_files(
    name: str, scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    content, message = BAD_TASK_FILES[name]
    path = tmp_path / name
    path.write_text(content)
    assert main(_run_args(scene_dir, tmp_path, profile_yaml, "--tasks", str(path))) == 2
    err = _one_line_error(capsys)
    assert name in err and message in err


def test_run_rejects_a_missing_tasks_file(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_run_args(scene_dir, tmp_path, profile_yaml, "--tasks", str(tmp_path / "none.yaml"))) == 2
    assert "none.yaml" in _one_line_error(capsys)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--param", "no_such_param=1"], "no_such_param"),
        (["--param", "top_k=0"], "top_k"),
        (["--param", "top_k=many"], "top_k"),
        (["--param", "fusion=median"], "fusion"),
        (["--param", "top_k"], "NAME=VALUE"),
        (["--param", "top_k=[1"], "top_k"),
        (["--params", "missing-params.yaml"], "missing-params.yaml"),
        (["--task", "  "], "task"),
        (["--profile", "no-such-profile.yaml"], "no-such-profile.yaml"),
    ],
)
def test_run_rejects_bad_arguments(
    extra: list[str],
    message: str,
    scene_dir: Path,
    profile_yaml: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = _run_args(scene_dir, tmp_path, profile_yaml, "--task", "red chair", *extra)
    assert main(args) == 2
    assert message in _one_line_error(capsys)
    assert not (tmp_path / "out" / "result").exists()


def test_run_rejects_a_malformed_params_file(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("top_k: [3\n")
    args = _run_args(scene_dir, tmp_path, profile_yaml, "--task", "cup", "--params", str(params))
    assert main(args) == 2
    assert "params.yaml" in _one_line_error(capsys)


def test_run_rejects_a_missing_scene(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "no-scene"
    assert main(_run_args(missing, tmp_path, profile_yaml, "--task", "cup")) == 2
    assert "no-scene" in _one_line_error(capsys)


SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"


def test_run_refuses_a_point_cloud_in_one_line(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An xyz-only point_cloud.ply (COLMAP's points3D as PLY) was told to run splat-transform on
    it, which refuses it; the refusal says what the file is and how to train a splat."""
    from tests.core.scene.test_point_clouds import xyz_cloud

    scene = copy_scene(SAMPLE, tmp_path / "scene")
    xyz_cloud(scene / "point_cloud.ply")
    assert main(_run_args(scene, tmp_path, profile_yaml, "--task", "cup")) == 2
    err = _one_line_error(capsys)
    assert "point_cloud.ply: a point cloud" in err and "ns-train splatfacto" in err, err
    assert "splat-transform" not in err


def _error_lines(capsys: pytest.CaptureFixture[str]) -> list[str]:
    lines = capsys.readouterr().err.strip().splitlines()
    assert all(line.startswith("bfields: error:") for line in lines) and "Traceback" not in "".join(lines)
    return lines


def test_run_reports_no_tasks_and_no_cameras_together(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 45: this said "no tasks given", and only on the next run "no cameras found"."""
    scene = tmp_path / "scene"
    scene.mkdir()
    shutil.copy(SAMPLE / "point_cloud.ply", scene / "point_cloud.ply")
    assert main(_run_args(scene, tmp_path, profile_yaml)) == 2
    lines = _error_lines(capsys)
    assert len(lines) == 2, lines
    assert "no tasks given" in lines[0] and "no cameras found" in lines[1], lines


def _shrink(image: Path) -> None:
    with Image.open(image) as img:
        small = img.resize((img.width // 2, img.height // 2))
    small.save(image)


def test_run_reports_a_wrong_image_size_before_the_alignment_check(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 45: the wrong size came after the alignment check had rendered (its report printed
    first, seconds in); now it comes before the check runs, so no alignment report is printed."""
    scene = copy_scene(SAMPLE, tmp_path / "scene")
    _shrink(scene / "images" / "frame_00003.png")
    assert main(_run_args(scene, tmp_path, profile_yaml)) == 2
    err = capsys.readouterr().err
    assert "alignment" not in err, err
    assert err.startswith("bfields: error:") and len(err.strip().splitlines()) == 1, err
    assert "frame_00003.png: image is 160x120 but its camera" in err and "transforms.json" in err
    assert not (tmp_path / "out").exists()


def test_run_reports_every_input_problem_of_one_run(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A missing tasks file, a missing image, two images of the wrong size and a bad parameter:
    one run, one line each."""
    scene = copy_scene(SAMPLE, tmp_path / "scene")
    (scene / "images" / "frame_00007.png").unlink()
    _shrink(scene / "images" / "frame_00003.png")
    _shrink(scene / "images" / "frame_00004.png")
    args = _run_args(
        scene, tmp_path, profile_yaml, "--tasks", str(tmp_path / "none.yaml"), "--param", "top_k=0"
    )
    assert main(args) == 2
    lines = _error_lines(capsys)
    assert len(lines) == 4, lines
    assert "none.yaml" in lines[0] and "top_k" in lines[1]
    assert "frame_00007.png" in lines[2] and "drop those frames from transforms.json" in lines[2]
    assert "2 images are not their cameras' size" in lines[3] and "frame_00004.png is 160x120" in lines[3]


@pytest.mark.slow
def test_run_prints_the_alignment_score(
    scene_dir: Path, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = _run_args(scene_dir, tmp_path, profile_yaml, "--task", "red chair", "--param", "max_frames=2")
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "alignment ok: render-vs-photo score" in err


@pytest.mark.parametrize(
    "change, cause",
    [
        (lambda f: move_splat(f, scale=0.5, shift=(0.4, 0.0, 0.0)), "dataparser_transforms.json"),
        (flip_camera_convention, "OpenGL"),
    ],
    ids=["scaled-0.5-shifted-0.4m", "opengl-flipped-cameras"],
)
@pytest.mark.slow
def test_run_refuses_a_splat_that_does_not_line_up(
    change, cause: str, profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = change(copy_scene(SAMPLE, tmp_path / "scene"))
    assert main(_run_args(scene, tmp_path, profile_yaml)) == 2
    err = _one_line_error(capsys)
    assert "alignment:" in err and cause in err and "--param alignment_check=false" in err
    assert not (tmp_path / "out" / "result").exists()  # refused before any stage ran


@pytest.mark.slow
def test_run_with_the_check_off_runs_a_misaligned_scene(
    profile_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = move_splat(copy_scene(SAMPLE, tmp_path / "scene"), scale=0.5, shift=(0.4, 0.0, 0.0))
    args = _run_args(
        scene, tmp_path, profile_yaml, "--param", "alignment_check=false", "--param", "max_frames=2"
    )
    assert main(args) == 0
    assert "alignment check: off" in capsys.readouterr().err


def test_calibrate_from_scores_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scores = tmp_path / "scores.csv"
    scores.write_text("score,label\n0.30,1\n0.26,1\n0.28,1\n0.19,0\n0.21,0\n0.20,0\n")
    out = tmp_path / "cal.json"
    assert main(["calibrate", "--scores", str(scores), "--model-id", "clip-x@abc", "--out", str(out)]) == 0
    assert "mu0=0.2000" in capsys.readouterr().out
    cal = load_calibration(out, model_id="clip-x@abc")
    assert cal.mu0 == pytest.approx(0.20)
    assert cal.mu1 == pytest.approx(0.28)
    assert cal.s == pytest.approx(0.02)  # sample std of the positives, the paper's choice
    assert (cal.num_positive, cal.num_negative) == (3, 3)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("value,label\n0.3,1\n0.2,0\n", "header"),
        ("score,label\n0.3,1\nhigh,0\n0.2,0\n", "cannot read"),
        ("score,label\n0.3,1\n0.31,1\n", "negative"),
        ("score,label\n0.3,1\n0.2\n0.25,0\n", "cannot read"),
        ("score,label\n0.1,1\n0.12,1\n0.3,0\n0.31,0\n", "mu1"),
    ],
)
def test_calibrate_rejects_bad_csv(
    content: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scores = tmp_path / "scores.csv"
    scores.write_text(content)
    out = tmp_path / "cal.json"
    assert main(["calibrate", "--scores", str(scores), "--model-id", "m@1", "--out", str(out)]) == 2
    assert message in _one_line_error(capsys)
    assert not out.exists()


def test_calibrate_rejects_a_missing_scores_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = [
        "calibrate",
        "--scores",
        str(tmp_path / "none.csv"),
        "--model-id",
        "m@1",
        "--out",
        str(tmp_path / "c.json"),
    ]
    assert main(args) == 2
    assert "none.csv" in _one_line_error(capsys)


def test_calibrate_scores_need_a_model_id(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scores = tmp_path / "scores.csv"
    scores.write_text("score,label\n0.30,1\n0.26,1\n0.19,0\n0.21,0\n")
    assert main(["calibrate", "--scores", str(scores), "--out", str(tmp_path / "c.json")]) == 2
    assert "--model-id" in _one_line_error(capsys)
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("value", ["-1", "four"])
def test_eval_rejects_a_bad_view_count(
    value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(
            ["eval", "--suite-dir", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--lerf-views", value]
        )
    assert exit_info.value.code == 2
    assert "--lerf-views" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()  # rejected before generating anything


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--seeds", "7,7"),
        ("--seeds", ",".join(str(seed) for seed in range(41))),
        ("--regime", "weak"),
        ("--seeds", "a,b"),
        ("--seeds", "-1"),
        ("--scenes", "11"),
        ("--scenes", "2"),
    ],
)
def test_eval_rejects_bad_scene_choices(
    option: str, value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "--suite-dir", str(tmp_path / "s"), "--out", str(tmp_path / "o"), option, value])
    assert exit_info.value.code == 2
    assert option in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_calibrate_is_one_typed_call(tmp_path: Path) -> None:
    """The library entry point needs no argparse: a `CalibrationRequest` in, a `Calibration` out
    (and the file written); a request with two sources or none is refused as bad input."""
    from bayesian_fields_core.errors import InputError
    from bayesian_fields_core.eval.calibration import fit as entry

    scores = tmp_path / "scores.json"
    scores.write_text('{"positive": [0.30, 0.26, 0.28], "negative": [0.19, 0.21, 0.20]}')
    out = tmp_path / "cal.json"
    cal = entry.calibrate(entry.CalibrationRequest(out=out, scores=scores, model_id="clip-x@abc"))
    assert (cal.mu0, cal.mu1) == pytest.approx((0.20, 0.28))
    assert load_calibration(out, model_id="clip-x@abc") == cal
    for bad in (
        entry.CalibrationRequest(out=out),
        entry.CalibrationRequest(out=out, scores=scores, scenes=(tmp_path,), model_id="m@1"),
    ):
        with pytest.raises(InputError, match="either a score file or scenes"):
            entry.calibrate(bad)
