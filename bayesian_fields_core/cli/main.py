"""`bfields`: the command line for people.

One module per verb (`VERBS`), each with `register(subparsers)` and `run(args) -> int`, the shape
of the service's client verbs; this module only assembles the parser from them and from the verbs
installed plug-ins add (entry-point group `CLI_PLUGIN_GROUP`: the service's `submit`, `status`,
`fetch`, `batch` and `serve`), then runs the chosen verb. Input errors print one clear line and
exit with status 2, never a traceback.

Building the parser imports no verb's machinery (torch, scipy, the pipeline): each verb imports
what it needs when it runs, so `bfields --help` and argument errors are quick
(`tests/core/cli/test_cli_parser.py`).
"""

from __future__ import annotations

import sys
from importlib.metadata import entry_points

from bayesian_fields_core.cli import (
    cache_command,
    calibrate_command,
    compare_command,
    eval_command,
    export_command,
    generate_command,
    params_command,
    run_command,
    view_command,
)
from bayesian_fields_core.cli.job_options import BfieldsParser
from bayesian_fields_core.errors import BayesianFieldsError, InputError, InputErrors, InvariantError

CLI_PLUGIN_GROUP = "bayesian_fields.cli"
"""Entry points here are called with the subparsers and may add verbs."""

VERBS = (
    run_command,
    params_command,
    cache_command,
    generate_command,
    eval_command,
    calibrate_command,
    view_command,
    export_command,
    compare_command,
)
"""The library's own verbs, in the order `bfields --help` lists them."""


def build_parser() -> BfieldsParser:
    """The `bfields` parser: the library's verbs, then those of installed plug-ins."""
    parser = BfieldsParser(
        prog="bfields", description="Task-driven semantic maps on Gaussian splats (Bayesian Fields)."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages (as run -v)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=BfieldsParser)
    for verb in VERBS:
        verb.register(sub)
    for plugin in entry_points(group=CLI_PLUGIN_GROUP):
        plugin.load()(sub)
    return parser


def _one_line(exc: Exception) -> str:
    """Messages that quote a YAML or validation error span lines; the CLI prints one."""
    return " ".join(str(exc).split())


def main(argv: list[str] | None = None) -> int:
    """Parse `argv`, run the verb; the exit status (2 for bad input, 1 for a failure)."""
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
        for problem in exc.errors if isinstance(exc, InputErrors) else [exc]:  # one line each
            print(f"bfields: error: {_one_line(problem)}", file=sys.stderr)
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


__all__ = ["CLI_PLUGIN_GROUP", "VERBS", "build_parser", "main"]
