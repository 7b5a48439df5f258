"""The `bfields view` command: load a local result (or fetch a job's from a server), start the
viewer, print its URL, open a browser when there is one, serve until Ctrl-C."""

from __future__ import annotations

import argparse
import os
import sys
import time
import webbrowser
from importlib.metadata import entry_points
from pathlib import Path

from bayesian_fields_core.cli.arguments import int_at_least
from bayesian_fields_core.cli.cache_command import DEFAULT_CACHE_DIR
from bayesian_fields_core.cli.cache_folder import VIEW_DIR
from bayesian_fields_core.errors import InputError

JOB_DOWNLOAD_GROUP = "bayesian_fields.job_download"
"""Entry point: `download(job_id, out, *, server, api_key)`, lent by the service client."""


def register(sub: argparse._SubParsersAction) -> None:
    """Add `view` to the `bfields` parser (the viewer itself is imported when it starts)."""
    view = sub.add_parser("view", help="look at a result in the browser (needs the 'view' extra)")
    view.add_argument("result", nargs="?", help="run folder of `bfields run --out` (or its result/ folder)")
    view.add_argument("--job", help="instead: a job id on the server (its result is downloaded first)")
    view.add_argument(
        "--server", help="API base URL for --job (default: $BFIELDS_SERVER or http://127.0.0.1:8000)"
    )
    view.add_argument("--api-key", help="API key for --job (default: $BFIELDS_API_KEY)")
    view.add_argument("--download-dir", help="where --job results go (default: ~/.cache/bfields/view/JOB)")
    view.add_argument("--scene", help="scene folder (default: the one summary.json records)")
    view.add_argument("--host", default="127.0.0.1")
    view.add_argument("--port", type=int, default=8080)
    view.add_argument(
        "--max-gaussians", type=int_at_least(1), metavar="N",
        help="cap on Gaussians sent to the browser (default: the viewer's, "
        "viewer.data.DEFAULT_MAX_GAUSSIANS; selected objects are always kept)",
    )  # fmt: skip
    view.add_argument("--no-browser", action="store_true", help="do not open a browser")
    view.set_defaults(func=run)


def _fetch_job(args: argparse.Namespace) -> Path:
    """Download job `args.job`'s result through the installed service client (a plug-in)."""
    downloaders = list(entry_points(group=JOB_DOWNLOAD_GROUP))
    if not downloaders:
        raise InputError("--job needs the service client (install the project with its 'api' extra)")
    out = Path(args.download_dir) if args.download_dir else DEFAULT_CACHE_DIR / VIEW_DIR / args.job
    server = args.server or os.environ.get("BFIELDS_SERVER", "http://127.0.0.1:8000")
    api_key = args.api_key or os.environ.get("BFIELDS_API_KEY")
    downloaders[0].load()(args.job, out, server=server, api_key=api_key)
    return out


def run(args: argparse.Namespace) -> int:
    """Load the result, start the viewer, serve until Ctrl-C."""
    try:
        from bayesian_fields_core.viewer.server import ResultViewer
    except ImportError:
        raise InputError("the viewer needs the 'view' extra: pip install 'bayesian-fields[view]'") from None
    from bayesian_fields_core.viewer.data import DEFAULT_MAX_GAUSSIANS, load_view

    if bool(args.result) == bool(args.job):
        raise InputError("give a result folder or --job ID (one of them)", source="bfields view")
    t0 = time.perf_counter()
    folder = _fetch_job(args) if args.job else Path(args.result)
    data = load_view(
        folder,
        scene_dir=Path(args.scene) if args.scene else None,
        max_gaussians=args.max_gaussians or DEFAULT_MAX_GAUSSIANS,
    )
    viewer = ResultViewer(data, host=args.host, port=args.port)
    print(
        f"viewer ready in {time.perf_counter() - t0:.1f} s: {viewer.url}  "
        f"({len(data.kept):,} of {data.total_gaussians:,} Gaussians, {len(data.tasks)} tasks; Ctrl-C to stop)",
        flush=True,
    )
    if not args.no_browser:
        try:
            webbrowser.open(viewer.url)
        except webbrowser.Error:
            pass
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        print("bfields view: stopped", file=sys.stderr)
    finally:
        viewer.stop()
    return 0
