"""`bfields export RESULT --task T [--rank K | --object ID ...] --format F [--out FILE]`: a task's
objects (or chosen objects) as a splat file another tool opens; `--all-tasks` writes one file per
task. The work is `results.splat_export`; this module only parses and prints."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bayesian_fields_core.cli.arguments import int_at_least

FORMAT_NAMES = "ply, compressed-ply, spz, splat, glb, sog"
"""What --format accepts, for the help text. The source is the format table (`scene.formats.registry`,
each row's `export`, listed by `formats.write.EXPORT_FORMATS`); this module does not import it so
that `bfields --help` stays light (the table imports numpy); a test keeps them equal."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `export` verb."""
    export = subparsers.add_parser(
        "export",
        help="write a task's objects as a splat file other tools open (.ply, .spz, ...)",
        description="Write objects of a result as a splat: every attribute of the input splat, in "
        "the splat file's frame. Example: bfields export out/demo --task mug --format spz",
    )
    export.add_argument("result", help="run folder of `bfields run --out` (or its result/ folder)")
    export.add_argument(
        "--task", help="the task whose answers to export: its text, or a unique part of it ('mug')"
    )
    export.add_argument(
        "--all-tasks", action="store_true", help="one file per answered task (--out is a folder)"
    )
    pick = export.add_mutually_exclusive_group()
    pick.add_argument("--rank", type=int_at_least(1), help="only the task's answer at this rank (1 = best)")
    pick.add_argument(
        "--object", type=int_at_least(0), nargs="+", dest="objects", metavar="ID",
        help="these object ids (the table's 'object' column) instead of a task's answers",
    )  # fmt: skip
    export.add_argument("--format", default="ply", help=f"{FORMAT_NAMES} (default ply)")
    export.add_argument(
        "--out", help="file to write (folder with --all-tasks; default: RESULT/exported/<task>.<format>)"
    )
    export.add_argument("--scene", help="scene folder the run read (default: the one summary.json records)")
    export.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export, then print each file written (one per line on stdout: the output pipes into other
    tools); with --all-tasks, each task with no answer gets a line on stderr saying why."""
    from bayesian_fields_core.errors import InputError
    from bayesian_fields_core.results.splat_export import export_all_tasks, export_objects
    from bayesian_fields_core.scene.formats.write import check_format

    check_format(args.format)
    if args.all_tasks:
        if args.task or args.objects:
            raise InputError(
                "--all-tasks exports every task's answers; drop --task / --object", source="bfields export"
            )
        exports = export_all_tasks(
            args.result, args.out, rank=args.rank, fmt=args.format, scene_dir=args.scene
        )
        for path in exports.written.values():
            print(path)
        for task, why in exports.unanswered.items():  # stderr: stdout stays a list of files
            print(f"{json.dumps(task)}: not found, no file written ({why})", file=sys.stderr)
        return 0
    path = export_objects(
        args.result,
        args.out,
        task=args.task,
        rank=args.rank,
        object_ids=args.objects,
        fmt=args.format,
        scene_dir=Path(args.scene) if args.scene else None,
    )
    print(path)
    return 0
