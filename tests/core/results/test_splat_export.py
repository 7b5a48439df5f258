"""`bfields export` and `export_objects` on a small written result (issue 31, item 1): what is
picked, where the Gaussians come from when no scene folder is known, and the one-line errors.
The read-back by splat-transform and gsply of a real run's export is in
tests/core/results/test_sample_export_compare.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.cli.export_command import FORMAT_NAMES
from bayesian_fields_core.cli.main import main
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.obb import minimum_obb
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results import Result, SelectedObject
from bayesian_fields_core.results.splat_export import export_all_tasks, export_objects
from bayesian_fields_core.results.writer import write_result
from bayesian_fields_core.scene.formats.write import EXPORT_FORMATS
from bayesian_fields_core.scene.ply import read_ply
from bayesian_fields_core.scene.types import Gaussians

TASKS = ["pick up the orange mug", "get the cyan cube", "pick up the red lamp"]


@pytest.fixture
def written(tmp_path: Path) -> tuple[Path, Gaussians, np.ndarray]:
    """A result folder (no scene folder recorded) with per-object exports, its splat and ids."""
    rng = np.random.default_rng(1)
    n = 600
    g = Gaussians(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.normal(-4, 0.5, (n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(0, 0.3, (n, 4, 3)).astype(np.float32),
        extra={"nx": rng.normal(size=n).astype(np.float32)},
    )
    ids = rng.integers(-1, 5, n)

    def answer(o: int) -> SelectedObject:
        pts = g.means[ids == o]
        return SelectedObject(o, 0.9, len(pts), pts.mean(0), minimum_obb(pts))

    result = Result(
        tasks=TASKS,
        object_ids=ids,
        probabilities=np.full((5, 4), 0.25, np.float32),
        selections={TASKS[0]: [answer(3), answer(1)], TASKS[1]: [answer(2)], TASKS[2]: []},
    )
    write_result(LocalStore(tmp_path / "run"), "result/", result, gaussians=g)
    return tmp_path / "run", g, ids


def _rows(g: Gaussians) -> np.ndarray:
    return np.column_stack([g.means, g.log_scales, g.quats, g.opacity_logits, g.sh.reshape(len(g), -1)])


def test_a_task_rank_and_objects_from_the_results_own_exports(written, tmp_path: Path) -> None:
    folder, g, ids = written
    path = export_objects(folder, task="mug", rank=2)
    assert path == folder / "exported" / "pick-up-the-orange-mug-rank-2.ply"
    back = read_ply(path)
    np.testing.assert_array_equal(_rows(back), _rows(g.subset(ids == 1)))
    np.testing.assert_array_equal(back.extra["nx"], g.extra["nx"][ids == 1])  # every attribute kept
    both = read_ply(export_objects(folder, tmp_path / "both.ply", task=TASKS[0]))
    assert len(both) == int(np.isin(ids, [3, 1]).sum())
    assert len(read_ply(export_objects(folder, tmp_path / "o.ply", object_ids=[2]))) == int((ids == 2).sum())


def test_all_tasks_writes_one_file_per_answered_task(written, tmp_path: Path) -> None:
    folder, _, ids = written
    exports = export_all_tasks(folder, tmp_path / "all", fmt="ply")
    assert list(exports.written) == TASKS[:2]  # the lamp has no answer
    assert exports.unanswered == {TASKS[2]: "no object selected"}  # and says so
    assert len(read_ply(exports.written[TASKS[1]])) == int((ids == 2).sum())


def test_the_cli_names_each_format_it_writes() -> None:
    assert FORMAT_NAMES == ", ".join(EXPORT_FORMATS)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--task", "zebra"], "--task: no task 'zebra' in this result; its tasks: 'pick up the orange mug'"),
        (["--task", "up the"], "matches several tasks"),
        (["--task", "mug", "--rank", "3"], "--rank: task 'pick up the orange mug' has ranks 1..2, not 3"),
        (["--object", "7"], "--object: object 7 is not in this result (ids 0..4)"),
        (["--task", "cube", "--object", "3"], "object 3 is not an answer to 'get the cyan cube'"),
        (["--task", "lamp"], "has no answer"),
        (
            ["--task", "mug", "--format", "obj"],
            "unknown format 'obj'; use one of: ply, compressed-ply, spz, splat, glb, sog",
        ),
        ([], "say what to export: --task TEXT, --object ID or --all-tasks"),
    ],
)
def test_errors_are_one_line_naming_the_problem_and_the_fix(
    written, extra: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, _, _ = written
    assert main(["export", str(folder), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bfields: error: ") and message in err, err


def test_a_missing_result_or_scene_is_named(
    written, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["export", str(tmp_path / "nowhere"), "--task", "mug"]) == 2
    assert "nowhere: no such folder; give a run folder of `bfields run --out`" in capsys.readouterr().err
    folder, _, _ = written
    with pytest.raises(
        InputError, match="objects \\[0\\] have no .ply export in the result; pass --scene DIR"
    ):
        export_objects(folder, object_ids=[0])  # not an answer: no export of its own, no scene known


SH_REST_STEP = {"ply": 1e-6, "compressed-ply": 8 / 255 / 2 + 1e-4, "spz": 1 / 256 + 1e-6, "glb": 1e-6}
"""Largest error of a higher-band SH coefficient each format allows: PLY and glTF store float32;
PlayCanvas compressed PLY 8 bits over [-4, 4]; SPZ 8 bits, (q - 128) / 128."""


@pytest.mark.parametrize("fmt", list(SH_REST_STEP))
@pytest.mark.slow
def test_sh_bands_survive_the_export_in_their_frame(fmt: str, tmp_path: Path) -> None:
    """Degree-3 bands (turned with the axes for SPZ and glTF) read back by splat-transform and the
    project's readers as written, within the format's step."""
    from bayesian_fields_core.scene.formats import read_splat
    from bayesian_fields_core.scene.formats.write import SUFFIXES, write_splat
    from tests.core.scene.format_writers import sh3_sample
    from tests.support.splat_transform import convert

    sample = sh3_sample(Path(__file__).resolve().parents[3] / "samples" / "tabletop" / "point_cloud.ply")
    path = write_splat(tmp_path / f"sh3{SUFFIXES[fmt]}", sample, fmt)
    readers = [read_splat(path, max_gaussians=10**6)]
    if fmt != "glb":  # splat-transform does not read glTF
        readers.append(read_ply(convert(path, tmp_path / "back.ply")))
    for back in readers:
        assert back.sh_degree == 3
        np.testing.assert_allclose(back.sh[:, 1:], sample.sh[:, 1:], atol=SH_REST_STEP[fmt], rtol=0)
