"""The client verbs' arguments: `bfields submit | status | fetch | batch`.

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


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m bayesian_fields_service.client``) with the same sub-commands."""
    parser = BfieldsParser(prog="bfields-client")
    register_client_commands(parser.add_subparsers(dest="command", required=True, parser_class=BfieldsParser))
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["main", "register_client_commands"]
