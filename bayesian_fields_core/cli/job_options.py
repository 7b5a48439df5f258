"""The arguments the job verbs share, defined once so `run`, `submit`, `batch` and `eval` agree.

- ``--task TEXT`` (repeatable) or ``--tasks FILE``; without either, the scene's own `tasks.yaml`;
- ``--param NAME=VALUE`` (repeatable, values read as YAML scalars) over ``--params FILE``;
- ``--out DIR``, by default a fresh ``outputs/<scene>/<UTC time>/`` (printed);
- ``--config FILE``: a run configuration written beside an earlier result (`run_config`).

What applies to which verb (the verbs only take what they can honour): `run` takes all of them;
`submit` the tasks and parameters (the job's result stays on the server until `bfields fetch`);
`batch` the parameters, over its manifest's `parameters` (the manifest lists scenes and task
lists); `eval` the parameters, under every evaluated row (its tasks come with the ground truth).

The parser only: nothing here imports the pipeline, pydantic or a YAML reader at import time,
so `bfields --help` and argument errors stay fast (`tests/core/cli/test_cli_parser.py`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bayesian_fields_core.errors import InputError

if TYPE_CHECKING:
    from bayesian_fields_core.params import PipelineParams

SCENE_TASKS_FILE = "tasks.yaml"
"""A scene folder's own task list, used when no --task / --tasks is given."""

OUTPUTS_ROOT = Path("outputs")
"""Where a run without --out writes: `OUTPUTS_ROOT / <scene name> / <UTC time>` (relative to the
current folder)."""


class BfieldsParser(argparse.ArgumentParser):
    """An ArgumentParser with no abbreviated options (``--task`` must never be read as
    ``--tasks``) and an epilog computed only when help is printed (``epilog_fn``), so a verb whose
    help lists, say, every pipeline parameter costs nothing until someone asks for it."""

    def __init__(self, *args: Any, epilog_fn: Callable[[], str] | None = None, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.epilog_fn = epilog_fn

    def format_help(self) -> str:
        if self.epilog_fn is not None:
            self.epilog = self.epilog_fn()
        return super().format_help()


class _DeprecatedParamsAlias(argparse.Action):
    """``submit --parameters FILE``: the old spelling of ``--params FILE``; warns and stores there."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        print(
            f"{parser.prog}: warning: {option_string} is deprecated and will go; use --params FILE",
            file=sys.stderr,
        )
        namespace.params = values


def add_task_arguments(parser: argparse.ArgumentParser) -> None:
    """``--task TEXT`` (repeatable) or ``--tasks FILE``: one of them, else the scene's tasks.yaml."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--task", action="append", default=[], metavar="TEXT", help="a task (repeatable)")
    group.add_argument(
        "--tasks",
        metavar="FILE",
        help=f"tasks file (.yaml list, .json or one per line); default SCENE/{SCENE_TASKS_FILE}",
    )


def add_parameter_arguments(parser: argparse.ArgumentParser, *, deprecated_alias: bool = False) -> None:
    """``--params FILE`` then ``--param NAME=VALUE`` over it; `deprecated_alias` adds the hidden
    ``--parameters FILE`` that `submit` took before the verbs agreed."""
    parser.add_argument("--params", metavar="FILE", help="YAML file of pipeline parameters")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="one pipeline parameter, over --params (repeatable; `bfields params` lists them)",
    )
    if deprecated_alias:
        parser.add_argument("--parameters", action=_DeprecatedParamsAlias, help=argparse.SUPPRESS)


def add_out_argument(parser: argparse.ArgumentParser) -> None:
    """``--out DIR``, optional: `output_folder` picks a fresh one when it is left out."""
    parser.add_argument(
        "--out",
        metavar="DIR",
        help=f"output folder (default: a new {OUTPUTS_ROOT}/<scene>/<UTC time>/, printed)",
    )


def resolve_tasks(
    task: Sequence[str], tasks_file: str | None, scene_dir: Path, *, fallback: Sequence[str] | None = None
) -> list[str]:
    """The job's tasks: --task, else --tasks FILE, else `fallback` (a --config's tasks), else the
    scene's tasks.yaml; a clear error when there are none."""
    from bayesian_fields_core.job.task_list import load_tasks, normalise_tasks

    if task:
        return normalise_tasks(list(task), source="--task")
    if tasks_file:
        return load_tasks(tasks_file)
    if fallback:
        return normalise_tasks(list(fallback), source="--config tasks")
    default = scene_dir / SCENE_TASKS_FILE
    if default.is_file():
        return load_tasks(default)
    raise InputError(
        f"no tasks given: pass --tasks FILE or --task TEXT (or put a {SCENE_TASKS_FILE} in the scene)"
    )


def parameter_overrides(params_file: str | None, items: Sequence[str]) -> dict[str, Any]:
    """The raw parameters a verb was given: the --params file's mapping, then each --param (values
    parsed as YAML scalars); names are checked (`refuse_unknown`), values not yet."""
    import yaml

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
    for item in items:
        if "=" not in item:
            raise InputError(f"expected NAME=VALUE, got {item!r}", source="--param")
        name, value = item.split("=", 1)
        try:
            raw[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise InputError(
                f"cannot parse the value of {name.strip()!r}: {value!r}", source="--param"
            ) from None
    refuse_unknown(raw, source="--param" if not params_file else f"--param / {params_file}")
    return raw


def refuse_unknown(raw: dict[str, Any], *, source: str) -> None:
    """An unknown parameter name is refused with the nearest known names (a typo, mostly)."""
    import difflib

    from bayesian_fields_core.params import PipelineParams

    known = list(PipelineParams.model_fields)
    for name in raw:
        if name not in known:
            near = difflib.get_close_matches(str(name), known, n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(near)}?" if near else "; `bfields params` lists them"
            raise InputError(f"unknown parameter {name!r}{hint}", source=source)


def validate_parameters(raw: dict[str, Any]) -> PipelineParams:
    """`PipelineParams` from raw parameters, or a one-line error naming the first bad field."""
    from pydantic import ValidationError

    from bayesian_fields_core.params import PipelineParams

    try:
        return PipelineParams.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in first["loc"])
        raise InputError(f"{loc}: {first['msg']}", source="parameters") from None


def build_params(params_file: str | None, overrides: Sequence[str]) -> PipelineParams:
    """PipelineParams from an optional YAML file plus --param overrides, validated."""
    return validate_parameters(parameter_overrides(params_file, overrides))


def output_folder(out: str | None, scene_dir: Path, *, now: datetime | None = None) -> tuple[Path, bool]:
    """(the run's output folder, whether it was chosen here): `out` as given, else a new
    ``outputs/<scene>/<UTC time>/`` (a suffix when two runs start in the same second)."""
    if out:
        return Path(out), False
    stamp = (now or datetime.now(UTC)).strftime("%Y%m%dT%H%M%SZ")
    base = OUTPUTS_ROOT / (scene_dir.resolve().name or "scene") / stamp
    folder, n = base, 1
    while folder.exists():
        n += 1
        folder = base.with_name(f"{stamp}-{n}")
    return folder, True


__all__ = [
    "BfieldsParser",
    "OUTPUTS_ROOT",
    "SCENE_TASKS_FILE",
    "add_out_argument",
    "add_parameter_arguments",
    "add_task_arguments",
    "build_params",
    "output_folder",
    "parameter_overrides",
    "refuse_unknown",
    "resolve_tasks",
    "validate_parameters",
]
