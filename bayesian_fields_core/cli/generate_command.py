"""`bfields generate`: a synthetic benchmark scene (the generator's own options pass through)."""

from __future__ import annotations

import argparse


def _generator_options() -> str:
    """The generator's options, for `generate --help` (imported only when help is printed)."""
    from bayesian_fields_core.eval.synthetic.__main__ import generator_parser

    return "generator options (after OUT):\n" + generator_parser().format_help().partition("options:")[2]


def register(sub: argparse._SubParsersAction) -> None:
    """Add `generate` to the `bfields` parser."""
    parser = sub.add_parser(
        "generate",
        help="generate a synthetic benchmark scene",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog_fn=_generator_options,
    )
    parser.add_argument("out")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("extra", nargs=argparse.REMAINDER, help="options passed to the generator")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Generate the scene through the generator's own command line."""
    from bayesian_fields_core.eval.synthetic import main as synthetic_main

    return synthetic_main([args.out, "--seed", str(args.seed), *args.extra])


__all__ = ["register", "run"]
