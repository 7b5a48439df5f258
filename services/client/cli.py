"""What the service lends the `bfields` command line, through entry points (pyproject.toml).

- `register_client_commands(subparsers)` (group ``bayesian_fields.cli``): the client verbs
  `submit`, `status`, `fetch`, `batch`, and `serve`, which starts the HTTP API;
- `download_job(job_id, out, server=..., api_key=...)` (group ``bayesian_fields.job_download``):
  fetches a job's result for `bfields view --job`.

So the library's CLI never imports the service: a library-only install simply has fewer verbs.
Loading this module (as `bfields` does for every command, `--help` included) imports argparse and
the verbs' wiring only; httpx and the verbs' code come when a verb runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.client.verbs import register_client_commands as _register_client_verbs


def cmd_serve(args: argparse.Namespace) -> int:
    """`bfields serve`: the HTTP API in this process (uvicorn)."""
    try:
        import uvicorn
    except ImportError:
        raise InputError("the API needs the 'api' extra: pip install 'bayesian-fields[api]'") from None
    uvicorn.run("bayesian_fields_service.api.app:app", host=args.host, port=args.port, workers=args.workers)
    return 0


def register_client_commands(sub: argparse._SubParsersAction) -> None:
    """Add the service's verbs to `bfields`."""
    _register_client_verbs(sub)
    srv = sub.add_parser("serve", help="run the HTTP API (needs the 'api' extra)")
    srv.add_argument("--host", default="127.0.0.1")
    srv.add_argument("--port", type=int, default=8000)
    srv.add_argument("--workers", type=int, default=1)
    srv.set_defaults(func=cmd_serve)


def download_job(job_id: str, out: Path, *, server: str, api_key: str | None) -> None:
    """Download job `job_id`'s artifacts into `out` (for `bfields view --job`)."""
    from bayesian_fields_service.client.api import BFieldsClient, ClientError

    try:
        with BFieldsClient(server, api_key) as client:
            client.download_artifacts(job_id, out)
    except ClientError as exc:
        raise InputError(str(exc), source="--job") from None


__all__ = ["register_client_commands", "download_job", "cmd_serve"]
