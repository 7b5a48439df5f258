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
    # --seed is the generator's option (listed once, under its options; its default is the
    # SceneSpec's, or the --suite scene's). Accepted before OUT too, as it always was.
    parser.add_argument("--seed", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("extra", nargs=argparse.REMAINDER, help="options passed to the generator")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Generate the scene through the generator's own command line."""
    from bayesian_fields_core.eval.synthetic import main as synthetic_main

    seed = [] if args.seed is None else ["--seed", str(args.seed)]
    return synthetic_main([args.out, *seed, *args.extra])


__all__ = ["register", "run"]
