"""The client verbs' arguments: `bfields submit | status | fetch | batch | answers`.

`register_client_commands(subparsers)` adds them to a `bfields`-style parser. Only argparse and the
library's shared job arguments (`bayesian_fields_core.cli.job_options`) are imported here: the
verbs' machinery (httpx, rich, `commands`) is imported when a verb runs, so `bfields --help`,
which loads this plug-in, stays quick. `submit` and `batch` take the tasks and parameters the
way `bfields run` does; `submit --parameters FILE` is the hidden, deprecated spelling of
``--params FILE``.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bayesian_fields_core.cli.job_options import BfieldsParser, add_parameter_arguments, add_task_arguments
from bayesian_fields_service.client.defaults import DEFAULT_SERVER


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--server", help=f"API base URL (default: $BFIELDS_SERVER or {DEFAULT_SERVER})")
    p.add_argument("--api-key", help="API key (default: $BFIELDS_API_KEY)")


def _priority(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument("--priority", choices=("interactive", "bulk"), default=default,
                   help=f"class in your fair-share queue: interactive jobs go first (default: {default})")  # fmt: skip


def _call(name: str, **kwargs: Any) -> int:
    """Run the client verb `name` of `commands` (imported now, not when the parser is built)."""
    from bayesian_fields_service.client import commands

    return commands.run_verb(getattr(commands, name), **kwargs)


def _submit(a: argparse.Namespace) -> int:
    return _call("submit", scene_dir=a.scene_dir, tasks_file=a.tasks, task=a.task, server=a.server,
                 api_key=a.api_key, wait=a.wait, parameters=a.params, param=a.param,
                 priority=a.priority)  # fmt: skip


def _status(a: argparse.Namespace) -> int:
    return _call("status", job_id=a.job_id, server=a.server, api_key=a.api_key)


def _fetch(a: argparse.Namespace) -> int:
    return _call("fetch", job_id=a.job_id, out=a.out, server=a.server, api_key=a.api_key)


def _batch(a: argparse.Namespace) -> int:
    return _call("batch", manifest=a.manifest, server=a.server, api_key=a.api_key, wait=not a.no_wait,
                 out=a.out, priority=a.priority, params=a.params, param=a.param)  # fmt: skip


def _answers(a: argparse.Namespace) -> int:
    return _call("answers", batch_id=a.batch_id, everything=a.all, task=a.task, min_probability=a.min_probability,
                 fmt=a.format, out=a.out, server=a.server, api_key=a.api_key)  # fmt: skip


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number between 0 and 1") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not between 0 and 1")
    return value


def register_client_commands(subparsers: argparse._SubParsersAction) -> None:
    """Add submit/status/fetch/batch to a `bfields` argparse parser (handler in `func`)."""
    p = subparsers.add_parser("submit", help="upload a scene folder and submit a job to the service")
    p.add_argument("scene_dir")
    add_task_arguments(p)
    add_parameter_arguments(p, deprecated_alias=True)
    p.add_argument("--wait", action="store_true", help="poll until the job ends (exit 1 unless it succeeded)")
    _priority(p, "interactive")
    _common(p)
    p.set_defaults(func=_submit)

    p = subparsers.add_parser("status", help="show a job's state, stage, progress and timings")
    p.add_argument("job_id")
    _common(p)
    p.set_defaults(func=_status)

    p = subparsers.add_parser("fetch", help="download every artifact of a finished job")
    p.add_argument("job_id")
    p.add_argument("--out", required=True, help="output folder")
    _common(p)
    p.set_defaults(func=_fetch)

    p = subparsers.add_parser(
        "batch",
        help="run many scenes x task lists from a YAML manifest (its tasks; --param over its parameters)",
    )
    p.add_argument("manifest")
    add_parameter_arguments(p)
    p.add_argument("--out", help="download the results of succeeded jobs here (default: no download)")
    p.add_argument("--no-wait", action="store_true", help="submit and print the batch id only")
    _priority(p, "bulk")
    _common(p)
    p.set_defaults(func=_batch)

    p = subparsers.add_parser(
        "answers",
        help="a batch's answers, or one task's across every scene of yours (--all), as one table",
        description="Example: bfields answers b_0123... --task mug --format csv --out mugs.csv; "
        "bfields answers --all --task 'fire extinguisher' --min-probability 0.5",
    )
    p.add_argument("batch_id", nargs="?", help="the batch (leave out with --all)")
    p.add_argument("--all", action="store_true", help="every scene's latest succeeded job that asked --task")
    p.add_argument("--task", help="the task: its text, or a unique part of it (required with --all)")
    p.add_argument("--min-probability", type=_probability, help="only answers at least this probable (0-1)")
    p.add_argument("--format", choices=("table", "tsv", "csv", "json"), default="table",
                   help="table (default; whole when piped), tsv, csv or json (every column)")  # fmt: skip
    p.add_argument("--out", help="write to this file instead of stdout")
    _common(p)
    p.set_defaults(func=_answers)


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m bayesian_fields_service.client``) with the same sub-commands."""
    parser = BfieldsParser(prog="bfields-client")
    register_client_commands(parser.add_subparsers(dest="command", required=True, parser_class=BfieldsParser))
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["main", "register_client_commands"]
