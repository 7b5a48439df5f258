"""Labelled scores for calibration: the labelling rule by hand, then the command on the sample scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import bayesian_fields_core
from bayesian_fields_core.calibration.model import MAX_PRESENT_LOSS, Calibration, distribution_min_peak
from bayesian_fields_core.cli.main import main
from bayesian_fields_core.eval.calibration.ground_truth import TaskPeak, label_masks, scene_absent_tasks
from bayesian_fields_core.eval.calibration.not_found_fit import fit_answer_min_peak
from bayesian_fields_core.eval.synthetic import load_ground_truth
from bayesian_fields_core.objects.not_found import resolve_answer_min_peak

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"


def test_label_masks_by_hand() -> None:
    # Gaussians 0-3 belong to task 0's object, 4-5 to task 1's; Gaussian 6 to nothing.
    relevant = np.zeros((7, 2), dtype=bool)
    relevant[:4, 0] = True
    relevant[4:6, 1] = True
    # mask 0 sees 0,1,2,6 (3/4 task 0); mask 1 sees 3,4 (1/2 each); mask 2 sees 6; mask 3 nothing.
    gaussian_ids = np.array([0, 1, 2, 6, 3, 4, 6])
    mask_ids = np.array([0, 0, 0, 0, 1, 1, 2])
    pos, neg = label_masks(gaussian_ids, mask_ids, 4, relevant, positive_overlap=0.6)
    np.testing.assert_array_equal(pos, [[True, False], [False, False], [False, False], [False, False]])
    np.testing.assert_array_equal(neg, [[False, True], [False, False], [True, True], [False, False]])
    pos_half, _ = label_masks(gaussian_ids, mask_ids, 4, relevant, positive_overlap=0.5)
    assert pos_half[1].tolist() == [True, True]


@pytest.mark.slow
def test_calibrate_from_the_sample_scene_separates_the_classes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cal.json"
    assert main(["calibrate", "--scene", str(SAMPLE), "--max-frames", "4", "--out", str(out)]) == 0
    assert "positive" in capsys.readouterr().out
    cal = json.loads(out.read_text())
    assert cal["model_id"].startswith("tiny-clip@")
    assert cal["num_positive"] > 10 and cal["num_negative"] > cal["num_positive"]
    # The tiny CLIP scores relevant masks well above irrelevant ones.
    assert cal["mu1"] - cal["mu0"] > 0.2
    assert 0 < cal["s"] < 1


def test_calibrate_rejects_a_scene_without_ground_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibrate", "--scene", str(tmp_path), "--out", str(tmp_path / "c.json")]) == 2
    assert "gt.json" in capsys.readouterr().err
    assert not (tmp_path / "c.json").exists()


@pytest.mark.slow
def test_negative_sources_differ_as_documented(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The paper's recipe (tasks with no object in the scene) against every unrelated pair."""
    counts = {}
    for source in ("absent", "unrelated"):
        out = tmp_path / f"{source}.json"
        args = [
            "calibrate",
            "--scene",
            str(SAMPLE),
            "--max-frames",
            "3",
            "--negatives",
            source,
            "--out",
            str(out),
        ]
        assert main(args) == 0
        counts[source] = json.loads(out.read_text())
    # The sample has one absent task ("pick up the red lamp"), so its negatives are one score per
    # observed mask; the unrelated pairs include that task and every other one.
    assert counts["absent"]["num_positive"] == counts["unrelated"]["num_positive"]
    assert 0 < counts["absent"]["num_negative"] < counts["unrelated"]["num_negative"]


# ---- the "not found" threshold, fitted (issue 23, item 4) -------------------------------------


def _peaks(absent: list[float], present: list[float]) -> list[TaskPeak]:
    """Task peaks given as margins of CAL (turned into raw scores as the command records them)."""
    span = CAL.mu1 - CAL.mu0
    return [TaskPeak(f"absent {i}", True, CAL.mu0 + m * span) for i, m in enumerate(absent)] + [
        TaskPeak(f"present {i}", False, CAL.mu0 + m * span) for i, m in enumerate(present)
    ]


CAL = Calibration(model_id="m@1", mu0=-0.2, mu1=0.6, s=0.15)


def test_the_fit_catches_the_most_absent_tasks_within_the_allowed_loss() -> None:
    # 101 present tasks: three weak ones (0.6, 0.62, 0.64), the rest at 1.0 .. 1.97; absent ones
    # at 0.3, 0.5 and 0.97
    present = [0.6, 0.62, 0.64] + [1.0 + 0.01 * i for i in range(98)]
    fitted = fit_answer_min_peak(_peaks([0.3, 0.5, 0.97], present), CAL, max_present_loss=0.02)
    assert fitted.not_found_fit is not None and fitted.answer_min_peak is not None
    # catching 0.97 would lose the three weak present tasks (3 %): the fit stops below it, between
    # the highest absent peak it catches (0.5) and the next peak (0.6)
    assert fitted.answer_min_peak == pytest.approx(0.55)
    assert fitted.not_found_fit.absent_not_found == pytest.approx(2 / 3)
    assert fitted.not_found_fit.present_lost == 0.0
    looser = fit_answer_min_peak(_peaks([0.3, 0.5, 0.97], present), CAL, max_present_loss=0.05)
    assert looser.answer_min_peak == pytest.approx((0.97 + 1.0) / 2)
    assert looser.not_found_fit is not None and looser.not_found_fit.present_lost == pytest.approx(3 / 101)
    # the curve is kept: every distinct peak, absent share rising, present loss rising
    curve = np.array(looser.not_found_fit.curve)
    assert (
        np.all(np.diff(curve[:, 0]) > 0)
        and np.all(np.diff(curve[:, 1]) >= 0)
        and np.all(np.diff(curve[:, 2]) >= 0)
    )


def test_nothing_is_fitted_without_absent_or_present_tasks() -> None:
    assert fit_answer_min_peak(_peaks([], [0.9, 1.2]), CAL).answer_min_peak is None
    assert fit_answer_min_peak(_peaks([0.2], []), CAL).answer_min_peak is None
    # tasks without an answer are "not found" at any threshold: no part of the fit
    unanswered = [TaskPeak("absent", True, None), TaskPeak("present", False, 0.5)]
    assert fit_answer_min_peak(unanswered, CAL).answer_min_peak is None


def test_the_run_applies_the_fitted_threshold_else_the_distribution_one() -> None:
    likelihood = CAL.to_likelihood_params()
    assert resolve_answer_min_peak(0.7, CAL, likelihood) == 0.7
    assert resolve_answer_min_peak(None, CAL, likelihood) is None
    fitted = CAL.model_copy(update={"answer_min_peak": 0.61})
    assert resolve_answer_min_peak("calibrated", fitted, likelihood) == 0.61
    # without a fitted one: the margin a relevant view (N(mu1, s)) falls below 2 % of the time
    fallback = resolve_answer_min_peak("calibrated", CAL, likelihood)
    assert fallback == pytest.approx(distribution_min_peak(CAL.mu0, CAL.mu1, CAL.s))
    view_margins = (np.random.default_rng(0).normal(CAL.mu1, CAL.s, 200_000) - CAL.mu0) / (CAL.mu1 - CAL.mu0)
    assert np.mean(view_margins < fallback) == pytest.approx(MAX_PRESENT_LOSS, abs=0.002)
    assert resolve_answer_min_peak("calibrated", None, likelihood) == pytest.approx(fallback)


@pytest.mark.slow
def test_calibrate_fits_the_threshold_on_the_sample_keeping_the_likelihoods(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command end to end: the sample's one absent task ("pick up the red lamp") and seven
    present ones; the likelihoods of the kept file are copied, the threshold fitted in them."""
    kept = Path(bayesian_fields_core.__file__).parent / "models" / "tiny-clip" / "calibration.json"
    out = tmp_path / "cal.json"
    args = ["calibrate", "--scene", str(SAMPLE), "--max-frames", "8", "--keep-likelihoods", str(kept)]
    args += ["--absent-tasks", "0"]  # the scene's own tasks only
    assert main([*args, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "answer_min_peak" in printed and "trade-off" in printed
    cal = json.loads(out.read_text())
    original = json.loads(kept.read_text())
    assert {k: cal[k] for k in ("model_id", "mu0", "mu1", "s")} == {
        k: original[k] for k in ("model_id", "mu0", "mu1", "s")
    }
    fit = cal["not_found_fit"]
    assert fit["absent_tasks"] == 1 and fit["present_tasks"] >= 6
    assert fit["absent_not_found"] == 1.0 and fit["present_lost"] <= 0.02
    assert -10 < cal["answer_min_peak"] < 10
    # --keep-likelihoods without scenes is refused in one line
    assert (
        main(
            [
                "calibrate",
                "--scores",
                str(out),
                "--model-id",
                "m@1",
                "--keep-likelihoods",
                str(kept),
                "--out",
                str(tmp_path / "x.json"),
            ]
        )
        == 2
    )
    assert "--keep-likelihoods goes with --scene" in capsys.readouterr().err


# ---- extra absent tasks and the realistic regime's threshold (issue 46) -------------------------


def test_extra_absent_tasks_of_the_sample_name_nothing_it_holds() -> None:
    gt = load_ground_truth(SAMPLE)
    held = {(str(i.colour), i.kind) for i in gt.instances if i.category == "object"}
    extra = scene_absent_tasks(gt, 6)
    assert len(extra) == 6 and not set(extra) & set(gt.task_texts)
    assert not any(f" {c} {k}" in t for t in extra for c, k in held)
    assert scene_absent_tasks(gt, 6) == extra and scene_absent_tasks(gt, 0) == []


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_calibrate_in_the_realistic_regime_stores_the_threshold_the_regime_uses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`bfields calibrate --regime realistic` end to end on the sample with extra absent tasks: the
    file keeps the regime's likelihoods (the margins every run of the regime computes), counts the
    extra absent tasks in its fit, and is what the regime then applies."""
    from bayesian_fields_core.eval import regime
    from bayesian_fields_core.eval.regime import PAPER_LIKELIHOODS, RegimeModels
    from bayesian_fields_core.perception.models import load_models

    out = tmp_path / "realistic.json"
    args = ["calibrate", "--scene", str(SAMPLE), "--max-frames", "4", "--regime", "realistic"]
    assert main([*args, "--absent-tasks", "3", "--cache", str(tmp_path / "cache"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "likelihoods these scenes give" in printed
    cal = json.loads(out.read_text())
    assert "weak-evidence" in cal["model_id"]
    target = PAPER_LIKELIHOODS
    assert (cal["mu0"], cal["mu1"], cal["s"]) == (target.mu0, target.mu1, target.s)
    fit = cal["not_found_fit"]
    assert fit is not None, printed
    assert fit["absent_tasks"] > 1  # the sample's own absent task alone has at most one answer
    monkeypatch.setattr(regime, "REALISTIC_CALIBRATION", out)
    used = RegimeModels(load_models()).calibration
    assert used is not None and used.answer_min_peak == cal["answer_min_peak"]


def test_absent_tasks_and_cache_go_with_scenes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scores = tmp_path / "s.json"
    scores.write_text('{"positive": [0.3, 0.28], "negative": [0.2, 0.19]}')
    args = ["calibrate", "--scores", str(scores), "--model-id", "m@1", "--out", str(tmp_path / "c.json")]
    assert main([*args, "--absent-tasks", "3"]) == 2
    assert "--absent-tasks and --cache go with --scene" in capsys.readouterr().err
    assert not (tmp_path / "c.json").exists()
