"""`bfields params`: every pipeline parameter with its type, default and meaning (`params_table`)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add `params` to the `bfields` parser."""
    parser = sub.add_parser("params", help="list every pipeline parameter: type, default, meaning")
    fmt = parser.add_mutually_exclusive_group()
    fmt.add_argument("--markdown", action="store_true", help="as the README's Markdown table")
    fmt.add_argument("--json", action="store_true", help="as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the table as text, Markdown or JSON."""
    from bayesian_fields_core.cli import params_table

    if args.json:
        import json

        print(json.dumps([vars(r) for r in params_table.rows()], indent=2))
    else:
        print(params_table.markdown_table() if args.markdown else params_table.text_table(), end="")
    return 0


__all__ = ["register", "run"]
