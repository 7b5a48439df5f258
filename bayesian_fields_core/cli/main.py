"""`bfields`: the command line for people.

Local commands run the library in process (`run`, `eval`, `calibrate`, `generate`); the
service, when installed, plugs in its client verbs (`submit`, `status`, `fetch`, `batch`) and `serve`.
Input errors print one clear line and exit with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict, Unpack

from bayesian_fields_core.cli.arguments import int_at_least
from bayesian_fields_core.cli.cache_command import DEFAULT_CACHE_DIR
from bayesian_fields_core.errors import BayesianFieldsError, InputError, InvariantError
from bayesian_fields_core.job.artifacts import RESULT_PREFIX

if TYPE_CHECKING:
    from bayesian_fields_core.job.context import CancelFn, JobContext, Models, ProgressFn
    from bayesian_fields_core.job.scene_source import SceneSource
    from bayesian_fields_core.params import PipelineParams

CLI_PLUGIN_GROUP = "bayesian_fields.cli"
"""Entry points here are called with the subparsers and may add verbs."""


def _parse_param_overrides(items: list[str]) -> dict[str, Any]:
    """`--param top_k=3 --param knn_filter=false`: values parsed as YAML scalars."""
    import yaml

    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise InputError(f"expected NAME=VALUE, got {item!r}", source="--param")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise InputError(
                f"cannot parse the value of {name.strip()!r}: {value!r}", source="--param"
            ) from None
    return out


def build_params(params_file: str | None, overrides: list[str]) -> PipelineParams:
    """PipelineParams from an optional YAML file plus --param overrides, validated."""
    import yaml
    from pydantic import ValidationError

    from bayesian_fields_core.params import PipelineParams

    raw: dict[str, Any] = {}
    if params_file:
        try:
            loaded = yaml.safe_load(Path(params_file).read_text(encoding="utf-8"))
        except OSError as exc:
            raise InputError(f"cannot read: {exc.strerror or exc}", source=params_file) from None
        except yaml.YAMLError as exc:
            raise InputError(f"cannot parse YAML: {exc}", source=params_file) from None
        if not isinstance(loaded, dict):
            raise InputError("expected a mapping of parameter names to values", source=params_file)
        raw.update(loaded)
    raw.update(_parse_param_overrides(overrides))
    _refuse_unknown(raw, source="--param" if not params_file else f"--param / {params_file}")
    try:
        return PipelineParams.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in first["loc"])
        raise InputError(f"{loc}: {first['msg']}", source="parameters") from None


def _refuse_unknown(raw: dict[str, Any], *, source: str) -> None:
    """An unknown parameter name is refused with the nearest known names (a typo, mostly)."""
    import difflib

    from bayesian_fields_core.params import PipelineParams

    known = list(PipelineParams.model_fields)
    for name in raw:
        if name not in known:
            near = difflib.get_close_matches(str(name), known, n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(near)}?" if near else "; `bfields params` lists them"
            raise InputError(f"unknown parameter {name!r}{hint}", source=source)


def check_device(device: str | None) -> None:
    """Refuse a torch device this machine does not have, before any model is loaded."""
    if device is None or device == "cpu":
        return
    import torch

    if device.startswith("cuda"):
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        index = int(device.partition(":")[2] or 0)
        if index >= count:
            found = f"{count} CUDA device(s)" if count else "no CUDA device (a CPU-only torch, or no driver)"
            raise InputError(f"device {device!r} asked for, but torch finds {found}", source="--param device")
    elif device == "mps" and not torch.backends.mps.is_available():
        raise InputError("device 'mps' asked for, but torch finds no MPS device", source="--param device")


def _resolve_tasks(args: argparse.Namespace, scene_dir: Path) -> list[str]:
    from bayesian_fields_core.job.task_list import load_tasks, normalise_tasks

    if args.task:
        return normalise_tasks(args.task, source="--task")
    if args.tasks:
        return load_tasks(args.tasks)
    default = scene_dir / "tasks.yaml"
    if default.is_file():
        return load_tasks(default)
    raise InputError("no tasks given: pass --tasks FILE or --task TEXT (or put a tasks.yaml in the scene)")


class LocalContextOptions(TypedDict, total=False):
    """The `JobContext` fields `local_context` passes through (the others it sets itself)."""

    scene_prefix: str
    work_dir: Path | None
    allow_source_path: bool
    splat_transform: Path | None
    progress: ProgressFn
    should_cancel: CancelFn
    scene_source: SceneSource | None


def local_context(
    scene_dir: Path,
    out: Path,
    cache_dir: Path,
    tasks: list[str],
    params: PipelineParams,
    models: Models,
    **options: Unpack[LocalContextOptions],
) -> JobContext:
    """The `JobContext` of `bfields run`: the job in `out`, the caches in `cache_dir`.

    Cache keys are content digests, so one cache serves every scene wherever its folder is; the
    scene's own path reaches only the cache index, for `bfields cache ls`.
    """
    from bayesian_fields_core.job.context import JobContext
    from bayesian_fields_core.job.store import LocalStore

    return JobContext(
        store=LocalStore(out),
        job_prefix="",
        tasks=tasks,
        params=params,
        models=models,
        scene_store=LocalStore(cache_dir),
        cache_prefix="",
        scene_dir=scene_dir,
        **options,
    )


def cmd_run(args: argparse.Namespace) -> int:
    from bayesian_fields_core.cli.output import stderr_console
    from bayesian_fields_core.cli.progress import StageProgress
    from bayesian_fields_core.job.pipeline import check_inputs, load_models, run_job
    from bayesian_fields_core.job.store import LocalStore
    from bayesian_fields_core.results.reader import read_result

    console = stderr_console()
    scene_dir = Path(args.scene)
    if scene_dir.is_file() and scene_dir.name in ("config.yml", "cfg.yml"):
        scene_dir = scene_dir.parent  # a trainer's config names its run folder
    if not scene_dir.is_dir():
        raise InputError("not a folder", source=str(scene_dir))
    tasks = _resolve_tasks(args, scene_dir)
    params = build_params(args.params, args.param)
    check_device(params.device)
    models = load_models(args.profile, device=params.device)
    out = Path(args.out)
    cache_dir = Path(args.cache_dir) if args.cache_dir else DEFAULT_CACHE_DIR
    # Cache keys digest the Gaussians as loaded (after any --splat-transform), so a changed
    # transform cannot reuse stale visibility.
    ctx = local_context(
        scene_dir,
        out,
        cache_dir,
        tasks,
        params,
        models,
        allow_source_path=True,
        splat_transform=Path(args.splat_transform) if args.splat_transform else None,
    )
    # Loads the scene and checks that the splat lines up with its cameras and photos (one-line
    # InputError otherwise), before the progress bars start and before perception.
    check_inputs(ctx)  # parameter-implied input problems, before the alignment renders
    alignment = ctx.alignment()
    console.print(alignment.summary() if alignment is not None else "alignment check: off")
    with StageProgress(console, enabled=not args.quiet) as progress:
        ctx.progress = progress.update
        reports = run_job(ctx, force=True)
    result = read_result(LocalStore(out), RESULT_PREFIX)
    from bayesian_fields_core.cli.report import print_result

    print_result(result, reports, out, json_output=args.json)
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    from bayesian_fields_core.cli.cache_command import cache_ls, cache_prune

    cache_dir = Path(args.cache_dir) if args.cache_dir else DEFAULT_CACHE_DIR
    if args.cache_command == "ls":
        print(cache_ls(cache_dir, json_output=args.json))
    else:
        if args.older_than is None and args.max_size is None:
            raise InputError("give --older-than DUR and/or --max-size SIZE", source="cache prune")
        print(cache_prune(cache_dir, older_than_s=args.older_than, max_size=args.max_size))
    return 0


def cmd_params(args: argparse.Namespace) -> int:
    from bayesian_fields_core.cli import params_table

    if args.json:
        import json

        print(json.dumps([vars(r) for r in params_table.rows()], indent=2))
    else:
        print(params_table.markdown_table() if args.markdown else params_table.text_table(), end="")
    return 0


def cmd_generate(args: argparse.Namespace) -> int:
    from bayesian_fields_core.eval.synthetic import main as synthetic_main

    return synthetic_main([args.out, "--seed", str(args.seed), *args.extra])


def cmd_eval(args: argparse.Namespace) -> int:
    from bayesian_fields_core.eval.suite import run_suite

    if args.scene is not None or args.gt is not None:
        return _eval_clio_scene(args)
    if args.transform is not None or args.transform_key is not None:
        raise InputError("--transform and --transform-key go with --scene DIR --gt FILE", source="eval")
    run_suite(
        suite_dir=Path(args.suite_dir),
        out_dir=Path(args.out),
        n_scenes=args.scenes,
        profile=args.profile,
        markdown=args.markdown,
        lerf_views=args.lerf_views,
        seeds=args.seeds,
        not_found_curve=args.not_found_curve,
        suite=args.suite,
        breakdown=args.breakdown,
    )
    return 0


def _eval_clio_scene(args: argparse.Namespace) -> int:
    """`bfields eval --scene DIR --gt FILE [--transform FILE]`: Table 1 on one scene (Clio's format)."""
    from bayesian_fields_core.eval.clio_scene import run_clio_scene

    if args.scene is None or args.gt is None:
        raise InputError("--scene DIR and --gt FILE go together", source="eval")
    if args.seeds is not None:
        raise InputError("--seeds selects suite scenes; it does not go with --scene", source="eval")
    run_clio_scene(
        scene_dir=Path(args.scene),
        gt_file=Path(args.gt),
        out_dir=Path(args.out),
        transform_file=Path(args.transform) if args.transform else None,
        transform_key=args.transform_key,
        profile=args.profile,
        markdown=args.markdown,
        not_found_curve=args.not_found_curve,
    )
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from bayesian_fields_core.eval.calibration.fit import CalibrationRequest, calibrate

    request = CalibrationRequest(
        out=args.out,
        scores=args.scores,
        scenes=tuple(args.scene or ()),
        profile=args.profile,
        negatives=args.negatives,
        max_frames=args.max_frames,
        model_id=args.model_id,
        keep_likelihoods=args.keep_likelihoods,
    )
    cal = calibrate(request)
    print(
        f"calibration for {cal.model_id}: mu0={cal.mu0:.4f} mu1={cal.mu1:.4f} s={cal.s:.4f} "
        f"({cal.num_positive} positive, {cal.num_negative} negative scores) -> {request.out}"
    )
    fit = cal.not_found_fit
    if fit is not None and cal.answer_min_peak is not None:
        print(
            f"'not found' threshold answer_min_peak = {cal.answer_min_peak:.4f}: {100 * fit.absent_not_found:.0f}% "
            f"of {fit.absent_tasks} absent tasks not found, {100 * fit.present_lost:.1f}% of "
            f"{fit.present_tasks} present tasks lost (at most {100 * fit.max_present_loss:.0f}% allowed)"
        )
        print("trade-off (threshold: absent not found / present lost):")
        for t, absent, lost in fit.curve:
            print(f"  {t:8.4f}: {100 * absent:5.1f}% / {100 * lost:5.1f}%")
    elif request.scenes:
        print("no 'not found' threshold fitted (the scenes need present and absent tasks with answers)")
    return 0


def _suite_count(text: str) -> int:
    """argparse type: how many public suite scenes, 3 (the fewest that make a suite) to 10 (the
    five layouts with their own seeds, then re-seeded with the public `PUBLIC_RESEEDS`)."""
    from bayesian_fields_core.eval.synthetic.spec import MAX_SUITE_SCENES

    value = int_at_least(0)(text)
    if not 3 <= value <= MAX_SUITE_SCENES:
        raise argparse.ArgumentTypeError(f"must be 3 to {MAX_SUITE_SCENES}, got {value}")
    return value


def _suite_seeds(text: str) -> list[int]:
    """argparse type: comma-separated seeds that `suite_specs` accepts (1 to 10, distinct, >= 0)."""
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bfields", description="Task-driven semantic maps on Gaussian splats (Bayesian Fields)."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages (as run -v)")
    sub = parser.add_subparsers(dest="command", required=True)

    from bayesian_fields_core.cli.params_table import text_table

    run = sub.add_parser(
        "run",
        help="run the whole pipeline on a local scene folder",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="pipeline parameters (--param NAME=VALUE, or a --params YAML file):\n\n" + text_table(),
    )
    run.add_argument("scene", help="scene folder (splat .ply + cameras + images/)")
    run.add_argument(
        "--tasks", help="tasks file (.yaml list, .json or one per line); default SCENE/tasks.yaml"
    )
    run.add_argument("--task", action="append", default=[], help="a task (repeatable); overrides --tasks")
    run.add_argument("--out", required=True, help="output folder")
    run.add_argument("--profile", help="model profile YAML (default: bundled classical + tiny CLIP)")
    run.add_argument("--params", help="YAML file of pipeline parameters")
    run.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="one parameter")
    run.add_argument("--cache-dir", help=f"perception cache (default {DEFAULT_CACHE_DIR})")
    run.add_argument(
        "--splat-transform",
        metavar="FILE",
        help="splat -> cameras transform: a nerfstudio dataparser_transforms.json, or JSON "
        '{"camera_to_splat": 4x4} (gsplat normalisation) / {"splat_to_camera": 4x4}; '
        "overrides the scene folder's (README: Bring your own scene)",
    )
    run.add_argument("--json", action="store_true", help="print the summary as JSON")
    run.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bars and no messages but the alignment check, warnings, errors and the "
        "result; third-party "
        "progress bars and chatter are off unless -v",
    )
    run.add_argument(
        "-v",
        "--verbose",
        dest="run_verbose",
        action="store_true",
        help="also log cache hits and misses, model load times and per-stage timings "
        "(and let third-party libraries talk)",
    )
    run.set_defaults(func=cmd_run)

    prm = sub.add_parser("params", help="list every pipeline parameter: type, default, meaning")
    fmt = prm.add_mutually_exclusive_group()
    fmt.add_argument("--markdown", action="store_true", help="as the README's Markdown table")
    fmt.add_argument("--json", action="store_true", help="as JSON")
    prm.set_defaults(func=cmd_params)

    from bayesian_fields_core.cli.cache_command import parse_duration, parse_size

    cache = sub.add_parser("cache", help="list or prune the local perception/visibility cache")
    cache_sub = cache.add_subparsers(dest="cache_command", required=True)
    cache_ls = cache_sub.add_parser("ls", help="entries (scene + profile) with size and last use")
    cache_ls.add_argument("--json", action="store_true", help="print the entries as JSON")
    cache_prune = cache_sub.add_parser("prune", help="drop entries least recently used first")
    cache_prune.add_argument(
        "--older-than", type=parse_duration, metavar="DUR", help="drop entries unused for DUR (30m, 12h, 7d)"
    )
    cache_prune.add_argument(
        "--max-size", type=parse_size, metavar="SIZE", help="then keep at most SIZE (500M, 2G), LRU first"
    )
    for p in (cache_ls, cache_prune):
        p.add_argument("--cache-dir", help=f"the cache folder (default {DEFAULT_CACHE_DIR})")
    cache.set_defaults(func=cmd_cache)

    from bayesian_fields_core.eval.synthetic.__main__ import _parser as generator_parser

    gen = sub.add_parser(
        "generate",
        help="generate a synthetic benchmark scene",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="generator options (after OUT):\n" + generator_parser().format_help().partition("options:")[2],
    )
    gen.add_argument("out")
    gen.add_argument("--seed", type=int, default=0)
    gen.add_argument("extra", nargs=argparse.REMAINDER, help="options passed to the generator")
    gen.set_defaults(func=cmd_generate)

    from bayesian_fields_core.eval.synthetic.spec import SUITES

    ev = sub.add_parser("eval", help="evaluate the method, ablations and baselines on the synthetic suite")
    ev.add_argument(
        "--suite-dir", default="bench/_generated/suite", help="where suite scenes are generated/cached"
    )
    ev.add_argument("--out", default="bench/_generated/eval", help="where runs are written")
    ev.add_argument(
        "--suite",
        choices=SUITES,
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
        help="held-out scenes: re-seed the suite's layouts in turn with these seeds (1 to 10; "
        "replaces --scenes)",
    )
    ev.add_argument(
        "--not-found-curve",
        action="store_true",
        help="also print the 'not found' trade-off curve: threshold vs absent tasks answered "
        "'not found' and recall lost on present ones",
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
    ev.set_defaults(func=cmd_eval)

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
    cal.add_argument("--out", required=True, help="calibration JSON to write")
    cal.set_defaults(func=cmd_calibrate)

    from bayesian_fields_core.cli.view_command import add_view_parser

    add_view_parser(sub)

    from bayesian_fields_core.cli import compare_command, export_command

    export_command.register(sub)
    compare_command.register(sub)

    # Verbs of installed plug-ins: the service adds submit, status, fetch, batch and serve
    # (entry-point group `bayesian_fields.cli`, see pyproject.toml).
    for plugin in entry_points(group=CLI_PLUGIN_GROUP):
        plugin.load()(sub)
    return parser


def _one_line(exc: Exception) -> str:
    """Messages that quote a YAML or validation error span lines; the CLI prints one."""
    return " ".join(str(exc).split())


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from bayesian_fields_core.cli.output import configure_output, stderr_console

    if args.verbose or getattr(args, "run_verbose", False):
        configure_output(stderr_console(), "verbose")
    else:
        configure_output(stderr_console(), "quiet" if getattr(args, "quiet", False) else "normal")
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"bfields: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except InvariantError as exc:  # not the input's fault: say so, do not blame the user
        print(f"bfields: internal error (a bug, please report it): {_one_line(exc)}", file=sys.stderr)
        return 1
    except BayesianFieldsError as exc:
        print(f"bfields: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bfields: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["main", "build_parser", "build_params", "local_context"]
