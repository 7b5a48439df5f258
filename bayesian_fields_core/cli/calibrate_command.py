"""`bfields calibrate`: fit the likelihoods' mu0 / mu1 / s (and the "not found" threshold) and
write a calibration file."""

from __future__ import annotations

import argparse

from bayesian_fields_core.cli.arguments import int_at_least
from bayesian_fields_core.cli.eval_command import regime_name
from bayesian_fields_core.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    """Add `calibrate` to the `bfields` parser."""
    cal = sub.add_parser("calibrate", help="fit mu0/mu1/s of the likelihoods and write a calibration file")
    src = cal.add_mutually_exclusive_group(required=True)
    src.add_argument("--scores", help="CSV/JSON of (score, label) pairs; label 1 = relevant")
    src.add_argument("--scene", action="append", help="synthetic scene folder(s) with gt.json (repeatable)")
    cal.add_argument("--profile", help="model profile YAML (default bundled)")
    cal.add_argument(
        "--negatives",
        choices=("absent", "unrelated"),
        default="absent",
        help="with --scene: negatives from tasks with no object in the scene (paper) or every unrelated pair",
    )
    cal.add_argument("--max-frames", type=int, help="with --scene: use at most this many frames per scene")
    cal.add_argument("--model-id", help="model id recorded in the file (default: the encoder's)")
    cal.add_argument(
        "--keep-likelihoods",
        metavar="FILE",
        help="with --scene: keep mu0/mu1/s of this calibration and fit only the 'not found' threshold",
    )
    cal.add_argument(
        "--regime",
        type=regime_name,
        default="strong",
        help="with --scene: 'strong' scores the encoder as it is; 'realistic' the evaluation's "
        "weak-evidence embeddings (`bfields eval --regime`), to check them against the paper's "
        "likelihoods and fit that regime's 'not found' threshold",
    )
    cal.add_argument(
        "--absent-tasks",
        type=int_at_least(0),
        help="with --scene: extra absent tasks per scene, by the suite's rule for absent tasks, "
        "to fit the 'not found' threshold against (default 6; 0 = the scenes' own tasks only)",
    )
    cal.add_argument("--cache", metavar="DIR", help="with --scene: keep the perception cache in DIR")
    cal.add_argument("--out", required=True, help="calibration JSON to write")
    cal.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Fit, write, and print the fitted values and the 'not found' trade-off."""
    from bayesian_fields_core.eval.calibration.fit import CalibrationRequest, calibrate
    from bayesian_fields_core.objects.not_found import SCORE_MEANING

    if args.scores is not None and (args.absent_tasks is not None or args.cache is not None):
        raise InputError(
            "--absent-tasks and --cache go with --scene (a score file has no tasks)", source="calibrate"
        )
    request = CalibrationRequest(
        out=args.out,
        scores=args.scores,
        scenes=tuple(args.scene or ()),
        profile=args.profile,
        negatives=args.negatives,
        max_frames=args.max_frames,
        model_id=args.model_id,
        keep_likelihoods=args.keep_likelihoods,
        regime=args.regime,
        cache=args.cache,
        **({} if args.absent_tasks is None else {"absent_tasks": args.absent_tasks}),
    )
    cal = calibrate(request)
    print(
        f"calibration for {cal.model_id}: mu0={cal.mu0:.4f} mu1={cal.mu1:.4f} s={cal.s:.4f} "
        f"({cal.num_positive} positive, {cal.num_negative} negative scores) -> {request.out}"
    )
    fit = cal.not_found_fit
    if fit is not None and cal.answer_min_peak is not None:
        print(
            f"'not found' threshold answer_min_peak = {cal.answer_min_peak:.4f} (the best-view score a task's "
            f"best object needs; {SCORE_MEANING}): {100 * fit.absent_not_found:.0f}% "
            f"of {fit.absent_tasks} absent tasks not found, {100 * fit.present_lost:.1f}% of "
            f"{fit.present_tasks} present tasks lost (at most {100 * fit.max_present_loss:.0f}% allowed)"
        )
        print("trade-off (threshold: absent not found / present lost):")
        for t, absent, lost in fit.curve:
            print(f"  {t:8.4f}: {100 * absent:5.1f}% / {100 * lost:5.1f}%")
    elif request.scenes:
        print("no 'not found' threshold fitted (the scenes need present and absent tasks with answers)")
    return 0


__all__ = ["register", "run"]
