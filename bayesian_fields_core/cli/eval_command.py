"""`bfields eval`: Table 1 (and the LeRF table) on the synthetic suite, or on one scene with
Clio-format ground truth. Its tasks come with the ground truth; ``--param`` / ``--params`` (the
job verbs' shared arguments, `job_options`) apply under every evaluated row."""

from __future__ import annotations

import argparse
from pathlib import Path

from bayesian_fields_core.cli.arguments import int_at_least
from bayesian_fields_core.cli.job_options import (
    add_parameter_arguments,
    parameter_overrides,
    validate_parameters,
)
from bayesian_fields_core.errors import InputError


def _suite_name(text: str) -> str:
    """argparse type: one of the synthetic suites (`eval.synthetic.spec.SUITES`), read when used."""
    from bayesian_fields_core.eval.synthetic.spec import SUITES

    if text not in SUITES:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(SUITES)}, got {text!r}")
    return text


def _suite_count(text: str) -> int:
    """argparse type: how many public suite scenes, 3 (the fewest that make a suite) to 10 (the
    five layouts with their own seeds, then re-seeded with the public `PUBLIC_RESEEDS`)."""
    from bayesian_fields_core.eval.synthetic.spec import MAX_SUITE_SCENES

    value = int_at_least(0)(text)
    if not 3 <= value <= MAX_SUITE_SCENES:
        raise argparse.ArgumentTypeError(f"must be 3 to {MAX_SUITE_SCENES}, got {value}")
    return value


def _suite_seeds(text: str) -> list[int]:
    """argparse type: comma-separated seeds that `suite_specs` accepts (1 to
    `MAX_HELD_OUT_SCENES`, distinct, >= 0)."""
    from bayesian_fields_core.eval.synthetic.spec import suite_specs

    try:
        seeds = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    try:
        suite_specs(seeds)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return seeds


def _share(text: str) -> float:
    """argparse type: a share in [0, 1] (the outlier dial's `SceneSpec.outlier_share`)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {value:g}")
    return value


def _row_set(text: str) -> str:
    """argparse type: one of the row sets (`eval.suite.ROW_SETS`), read when used."""
    from bayesian_fields_core.eval.suite import ROW_SETS

    if text not in ROW_SETS:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(ROW_SETS)}, got {text!r}")
    return text


def regime_name(text: str) -> str:
    """argparse type: one of the perception regimes (`eval.regime.REGIMES`), read when used."""
    from bayesian_fields_core.eval.regime import REGIMES

    if text not in REGIMES:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(REGIMES)}, got {text!r}")
    return text


def register(sub: argparse._SubParsersAction) -> None:
    """Add `eval` to the `bfields` parser."""
    ev = sub.add_parser("eval", help="evaluate the method, ablations and baselines on the synthetic suite")
    ev.add_argument(
        "--suite-dir", default="bench/_generated/suite", help="where suite scenes are generated/cached"
    )
    ev.add_argument("--out", default="bench/_generated/eval", help="where runs are written")
    ev.add_argument(
        "--suite",
        type=_suite_name,
        default="tabletop",
        help="which synthetic suite: tabletop (orbiting cameras, whole objects) or capture "
        "(handheld walks, close-ups, border cuts, occluders, one-sided labels, texture, clutter)",
    )
    ev.add_argument(
        "--scenes",
        type=_suite_count,
        default=5,
        help="number of public suite scenes (3 to 10; 6-10 are the five layouts re-seeded)",
    )
    ev.add_argument("--profile", help="model profile YAML")
    add_parameter_arguments(ev)
    ev.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    ev.add_argument(
        "--lerf-views",
        type=int_at_least(0),
        default=4,
        help="views per scene for the LeRF-protocol table (rendered masks; 0 = skip it)",
    )
    ev.add_argument(
        "--seeds",
        type=_suite_seeds,
        metavar="S1,S2,...",
        help="held-out scenes: re-seed the suite's layouts in turn with these seeds (1 to 40; "
        "replaces --scenes)",
    )
    ev.add_argument(
        "--outliers",
        type=_share,
        default=0.0,
        metavar="S",
        help="the outlier dial (capture suite only): replace this share of each scene's frames by "
        "near, far and occluded views of its task objects, in equal parts (0 = the suite as it is; "
        "scenes with S > 0 are named <scene>-o<percent>)",
    )
    ev.add_argument(
        "--regime",
        type=regime_name,
        help="perception regime of the suite: realistic (default: each view as weak as a real CLIP's, "
        "the paper's mu0=0.20 mu1=0.27 s=0.035) or strong (the tiny CLIP's strong per-view evidence)",
    )
    ev.add_argument(
        "--not-found-curve",
        action="store_true",
        help="also print the 'not found' trade-off curve: threshold vs absent tasks answered "
        "'not found' and recall lost on present ones",
    )
    ev.add_argument(
        "--rows",
        type=_row_set,
        default="all",
        help="which rows to run: all (Table 1: the method, its ablations, w/o PE among them, and the baselines), "
        "full (the full method alone: its scores and the 'not found' answer, in a fraction of the time) or "
        "orphi (the full method and w/o OR-phi: the outlier dial's pair)",
    )
    ev.add_argument(
        "--breakdown",
        action="store_true",
        help="also print why GT objects were missed (merged neighbours, split objects, wrong "
        "instance, missed), per task for the full method and per task family for each row",
    )
    clio = ev.add_argument_group(
        "one scene with Clio-format ground truth (README: Table 1 on the Clio datasets)"
    )
    clio.add_argument("--scene", metavar="DIR", help="scene folder to evaluate instead of the suite")
    clio.add_argument(
        "--gt", metavar="FILE", help="Clio task YAML: task -> boxes {center, extents, rotation (w,x,y,z)}"
    )
    clio.add_argument(
        "--transform",
        metavar="FILE",
        help="COLMAP -> GT transform: {T: 4x4, scale} or Clio's scene_transforms.yaml (keyed by scene)",
    )
    clio.add_argument(
        "--transform-key", metavar="NAME", help="scene key in --transform (default: the scene folder's name)"
    )
    ev.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The suite, or one Clio-format scene when --scene / --gt are given."""
    base_params = parameter_overrides(args.params, args.param) or None
    if base_params:
        validate_parameters(base_params)  # a bad value is refused before any scene is generated
    if args.scene is not None or args.gt is not None:
        return _clio_scene(args, base_params)
    if args.transform is not None or args.transform_key is not None:
        raise InputError("--transform and --transform-key go with --scene DIR --gt FILE", source="eval")
    if args.outliers > 0 and args.suite != "capture":
        raise InputError(
            "--outliers is for --suite capture (tabletop scenes have no occluders)", source="eval"
        )
    from bayesian_fields_core.eval.regime import DEFAULT_REGIME
    from bayesian_fields_core.eval.suite import run_suite

    run_suite(
        suite_dir=Path(args.suite_dir),
        out_dir=Path(args.out),
        n_scenes=args.scenes,
        profile=args.profile,
        markdown=args.markdown,
        base_params=base_params,
        lerf_views=args.lerf_views,
        seeds=args.seeds,
        not_found_curve=args.not_found_curve,
        suite=args.suite,
        breakdown=args.breakdown,
        regime=args.regime or DEFAULT_REGIME,
        rows_shown=args.rows,
        outliers=args.outliers,
    )
    return 0


def _clio_scene(args: argparse.Namespace, base_params: dict[str, object] | None) -> int:
    """`bfields eval --scene DIR --gt FILE [--transform FILE]`: Table 1 on one scene (Clio's format)."""
    from bayesian_fields_core.eval.clio_scene import run_clio_scene

    if args.scene is None or args.gt is None:
        raise InputError("--scene DIR and --gt FILE go together", source="eval")
    if args.seeds is not None:
        raise InputError("--seeds selects suite scenes; it does not go with --scene", source="eval")
    if args.outliers > 0:
        raise InputError("--outliers makes suite scenes; it does not go with --scene", source="eval")
    if args.regime is not None:
        raise InputError(
            "--regime changes the suite's tiny CLIP; a --scene is scored with its profile's own encoder",
            source="eval",
        )
    run_clio_scene(
        scene_dir=Path(args.scene),
        gt_file=Path(args.gt),
        out_dir=Path(args.out),
        transform_file=Path(args.transform) if args.transform else None,
        transform_key=args.transform_key,
        profile=args.profile,
        markdown=args.markdown,
        base_params=base_params,
        not_found_curve=args.not_found_curve,
    )
    return 0


__all__ = ["register", "run"]
