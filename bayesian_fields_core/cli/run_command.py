"""`bfields run`: the whole pipeline on a local scene folder, in this process.

The arguments it shares with `submit`, `batch` and `eval` come from `job_options`; the run's full
configuration is written beside the result (`run_config`) and accepted back with ``--config``.
The pipeline, torch and the result reader are imported only when a run starts.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bayesian_fields_core.cli.job_options import (
    add_out_argument,
    add_parameter_arguments,
    add_task_arguments,
    output_folder,
    parameter_overrides,
    resolve_tasks,
    validate_parameters,
)
from bayesian_fields_core.errors import InputError

if TYPE_CHECKING:
    from bayesian_fields_core.cli.run_config import RunConfig
    from bayesian_fields_core.cli.trace_file import TraceFile
    from bayesian_fields_core.params import PipelineParams

OUTPUT_FORMATS = ("table", "tsv", "json")
"""What `run` prints on stdout: the answer table, tab-separated rows, or the summary as JSON."""


def _default_cache_dir() -> Path:
    from bayesian_fields_core.cli.cache_command import DEFAULT_CACHE_DIR

    return DEFAULT_CACHE_DIR


def _parameter_epilog() -> str:
    from bayesian_fields_core.cli.params_table import text_table

    return "pipeline parameters (--param NAME=VALUE, or a --params YAML file):\n\n" + text_table()


def register(sub: argparse._SubParsersAction) -> None:
    """Add `run` to the `bfields` parser."""
    parser = sub.add_parser(
        "run",
        help="run the whole pipeline on a local scene folder",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog_fn=_parameter_epilog,
    )
    parser.add_argument(
        "scene", nargs="?", help="scene folder (splat .ply + cameras + images/); default: --config's"
    )
    add_task_arguments(parser)
    add_out_argument(parser)
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="re-run the configuration an earlier run wrote (OUT/config.yaml); flags given beside it win",
    )
    parser.add_argument("--profile", help="model profile YAML (default: bundled classical + tiny CLIP)")
    add_parameter_arguments(parser)
    parser.add_argument(
        "--cache-dir", help="perception cache (default $XDG_CACHE_HOME/bfields, else ~/.cache/bfields)"
    )
    parser.add_argument(
        "--splat-transform",
        metavar="FILE",
        help="splat -> cameras transform: a nerfstudio dataparser_transforms.json, or JSON "
        '{"camera_to_splat": 4x4} (gsplat normalisation) / {"splat_to_camera": 4x4}; '
        "overrides the scene folder's (README: Bring your own scene)",
    )
    fmt = parser.add_mutually_exclusive_group()
    fmt.add_argument(
        "--format",
        choices=OUTPUT_FORMATS,
        default="table",
        help="table (at its natural width when piped), tsv (one row per answer) or json",
    )
    fmt.add_argument(
        "--json",
        dest="format",
        action="store_const",
        const="json",
        help="the same as --format json: the result's summary.json (one schema) plus a 'run' block",
    )
    parser.add_argument(
        "--trace",
        metavar="FILE",
        help="write the run's trace to FILE, one span a JSON line: the run, the model load, the "
        "input checks and each stage with its frame / mask / Gaussian counts",
    )
    parser.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bars and no messages but the alignment check, warnings, errors and the "
        "result; third-party progress bars and chatter are off unless -v",
    )
    parser.add_argument(
        "-v",
        "--verbose",
        dest="run_verbose",
        action="store_true",
        help="also log cache hits and misses, model load times and per-stage timings "
        "(and let third-party libraries talk)",
    )
    parser.set_defaults(func=run)


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


def _scene_folder(text: str) -> Path:
    scene_dir = Path(text)
    if scene_dir.is_file() and scene_dir.name in ("config.yml", "cfg.yml"):
        scene_dir = scene_dir.parent  # a trainer's config names its run folder
    if not scene_dir.is_dir():
        raise InputError("not a folder", source=str(scene_dir))
    return scene_dir


def run(args: argparse.Namespace) -> int:
    """Run the pipeline as `args` (and any --config) ask, write config.yaml, print the answers."""
    from bayesian_fields_core.cli.run_config import RunConfig, read_run_config

    base = read_run_config(Path(args.config)) if args.config else None
    scene = args.scene if args.scene is not None else (str(base.scene) if base else None)
    if scene is None:
        raise InputError("give a scene folder (or --config FILE of an earlier run)", source="bfields run")
    scene_dir = _scene_folder(scene)
    tasks, params, transform = _check_inputs(args, base, scene_dir)
    profile = Path(args.profile) if args.profile else (base.profile if base else None)
    out, chosen = output_folder(args.out, scene_dir)
    if chosen:
        print(f"output folder: {out}", file=sys.stderr)
    config = RunConfig(
        scene=scene_dir,
        tasks=tasks,
        parameters=params.model_dump(mode="json"),
        profile=profile,
        splat_transform=transform,
    )
    return _execute(args, config, params, out)


def _check_inputs(
    args: argparse.Namespace, base: RunConfig | None, scene_dir: Path
) -> tuple[list[str], PipelineParams, Path | None]:
    """(tasks, parameters, splat transform) of the run, after every input it needs was checked
    at once, before the models load and before the alignment check renders: the tasks, the
    parameters and the scene (`checks.inputs`). All problems are raised together."""
    from bayesian_fields_core.checks.inputs import check_run_inputs

    problems: list[InputError] = []
    tasks: list[str] = []
    params: PipelineParams | None = None
    try:
        tasks = resolve_tasks(args.task, args.tasks, scene_dir, fallback=base.tasks if base else None)
    except InputError as exc:
        problems.append(exc)
    try:
        raw = {**(base.parameters if base else {}), **parameter_overrides(args.params, args.param)}
        params = validate_parameters(raw)
    except InputError as exc:
        problems.append(exc)
    transform = (
        Path(args.splat_transform) if args.splat_transform else (base.splat_transform if base else None)
    )
    check_run_inputs(scene_dir, found=problems, allow_source_path=True, splat_transform=transform)
    assert params is not None  # a parameter problem was raised above
    return tasks, params, transform


def _execute(args: argparse.Namespace, config: RunConfig, params: PipelineParams, out: Path) -> int:
    """`_run_traced`, in a trace written to ``--trace FILE`` when given."""
    if not args.trace:
        return _run_traced(args, config, params, out, None)
    from bayesian_fields_core.cli.trace_file import TraceFile

    trace = TraceFile(Path(args.trace))
    attributes = {
        "bfields.scene": str(config.scene),
        "bfields.tasks": len(config.tasks),
        "bfields.out": str(out),
    }
    with trace.span("bfields run", attributes):
        return _run_traced(args, config, params, out, trace)


def _run_traced(
    args: argparse.Namespace, config: RunConfig, params: PipelineParams, out: Path, trace: TraceFile | None
) -> int:
    """Load the models, check the inputs, run the stages, write config.yaml, print the result."""
    import contextlib
    from dataclasses import replace

    from bayesian_fields_core.cli.output import stderr_console
    from bayesian_fields_core.cli.progress import StageProgress
    from bayesian_fields_core.cli.report import print_result
    from bayesian_fields_core.cli.run_config import running_versions, write_run_config
    from bayesian_fields_core.job.artifacts import RESULT_PREFIX
    from bayesian_fields_core.job.factories import local_job
    from bayesian_fields_core.job.pipeline import check_inputs, run_job
    from bayesian_fields_core.job.store import LocalStore
    from bayesian_fields_core.perception.models import load_models
    from bayesian_fields_core.results.reader import read_result

    def span(name: str) -> contextlib.AbstractContextManager[Any]:
        return trace.span(name) if trace is not None else contextlib.nullcontext()

    console = stderr_console()
    check_device(params.device)
    with span("load models"):
        models = load_models(str(config.profile) if config.profile else None, device=params.device)
    cache_dir = Path(args.cache_dir) if args.cache_dir else _default_cache_dir()
    # Cache keys digest the Gaussians as loaded (after any --splat-transform), so a changed
    # transform cannot reuse stale visibility.
    job = local_job(
        config.scene,
        out,
        cache_dir,
        config.tasks,
        params,
        models,
        allow_source_path=True,
        splat_transform=config.splat_transform,
    )
    # Loads the scene and checks that the splat lines up with its cameras and photos (one-line
    # InputError otherwise), before the progress bars start and before perception.
    with span("check inputs"):
        check_inputs(params, job.scene)  # parameter-implied input problems, before the alignment renders
        alignment = job.scene.alignment(job.runner.render_device(params))
    console.print(alignment.summary() if alignment is not None else "alignment check: off")
    with StageProgress(console, enabled=not args.quiet) as progress:
        around = trace.stage if trace is not None else None
        reports = run_job(replace(job, runner=replace(job.runner, progress=progress.update)), force=True,
                          around=around)  # fmt: skip
    config_path = write_run_config(out, replace(config, versions=running_versions()))
    result = read_result(LocalStore(out), RESULT_PREFIX)
    print_result(result, reports, out, output_format=args.format, config_path=config_path)
    return 0


__all__ = ["OUTPUT_FORMATS", "check_device", "register", "run"]
