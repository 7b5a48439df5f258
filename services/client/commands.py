"""`bfields submit | status | fetch | batch`: the service from the command line.

`register_client_commands(subparsers)` adds the four sub-commands to the `bfields` argparse
parser; each handler is also a plain function (`submit`, `status`, `fetch`, `batch`) returning an
exit code. The server comes from ``--server`` or ``BFIELDS_SERVER``, the key from ``--api-key``
or ``BFIELDS_API_KEY`` (so it stays out of shell history).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from rich.live import Live
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn
from rich.table import Table

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.task_list import load_tasks, normalise_tasks
from bayesian_fields_service.client.api import BFieldsClient, ClientError

DEFAULT_SERVER = "http://127.0.0.1:8000"
console = Console(stderr=True)


def _client(server: str | None, api_key: str | None) -> BFieldsClient:
    return BFieldsClient(
        server or os.environ.get("BFIELDS_SERVER", DEFAULT_SERVER),
        api_key or os.environ.get("BFIELDS_API_KEY"),
    )


def _upload(client: BFieldsClient, scene_dir: Path) -> dict[str, Any]:
    with Progress(TextColumn(f"upload {scene_dir.name}"), BarColumn(), DownloadColumn(), TransferSpeedColumn(),
                  console=console, transient=True) as bar:  # fmt: skip
        task = bar.add_task("upload", total=None)
        return client.upload_scene(
            scene_dir,
            on_total=lambda n: bar.update(task, total=n),
            on_bytes=lambda n: bar.advance(task, n),
        )


def _wait_with_bar(client: BFieldsClient, job_id: str, poll_s: float) -> dict[str, Any]:
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>5.1f}%"),
                  console=console, transient=True) as bar:  # fmt: skip
        task = bar.add_task(job_id, total=100)

        def update(job: dict[str, Any]) -> None:
            bar.update(
                task, completed=job["progress"], description=f"{job_id} {job['state']} {job['stage'] or ''}"
            )

        return client.wait(job_id, poll_s=poll_s, on_update=update)


def _print(obj: Any) -> None:
    print(json.dumps(obj, indent=2, sort_keys=True, default=str))


def _parameters(path: str | None) -> dict[str, Any]:
    if not path:
        return {}
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read parameters: {exc}", source=path) from None
    if not isinstance(data, dict):
        raise InputError("parameters must be a mapping", source=path)
    return data


def submit(scene_dir: str | Path, tasks_file: str | Path, *, server: str | None = None, api_key: str | None = None,
           wait: bool = False, parameters: str | None = None, poll_s: float = 1.0) -> int:  # fmt: skip
    """Upload a scene folder, submit a job for the task list; with `wait`, poll until it ends."""
    tasks = load_tasks(tasks_file)
    with _client(server, api_key) as client:
        scene = _upload(client, Path(scene_dir))
        console.print(f"scene {scene['id']}: {scene['summary'].get('frames')} frames, "
                      f"{scene['summary'].get('gaussians')} Gaussians")  # fmt: skip
        job = client.submit_job(scene["id"], tasks, parameters=_parameters(parameters),
                                idempotency_key=str(uuid.uuid4()))  # fmt: skip
        print(job["id"])
        if not wait:
            return 0
        final = _wait_with_bar(client, job["id"], poll_s)
        console.print(
            f"job {final['id']} {final['state']}" + (f": {final['error']}" if final["error"] else "")
        )
        return 0 if final["state"] == "succeeded" else 1


def status(job_id: str, *, server: str | None = None, api_key: str | None = None) -> int:
    with _client(server, api_key) as client:
        _print(client.job(job_id))
    return 0


def fetch(job_id: str, out: str | Path, *, server: str | None = None, api_key: str | None = None) -> int:
    """Download every artifact of a finished job into `out`."""
    with _client(server, api_key) as client:
        with Progress(TextColumn(f"fetch {job_id}"), DownloadColumn(), TransferSpeedColumn(), console=console,
                      transient=True) as bar:  # fmt: skip
            task = bar.add_task("fetch", total=None)
            files = client.download_artifacts(job_id, Path(out), on_bytes=lambda n: bar.advance(task, n))
    console.print(f"{len(files)} files in {out}")
    return 0


def _manifest(path: Path) -> dict[str, Any]:
    """A batch manifest: ``scenes`` (folders, or ``s_...`` ids of stored scenes), ``task_lists``
    (lists of tasks, or task files), optional ``parameters`` and ``model_profile``."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read batch manifest: {exc}", source=str(path)) from None
    if not isinstance(data, dict) or not data.get("scenes") or not data.get("task_lists"):
        raise InputError("expected a mapping with non-empty 'scenes' and 'task_lists'", source=str(path))
    task_lists = []
    for i, entry in enumerate(data["task_lists"]):
        if isinstance(entry, str):
            task_lists.append(load_tasks(path.parent / entry))
        else:
            task_lists.append(normalise_tasks(entry, source=f"{path}: task_lists[{i}]"))
    return {**data, "task_lists": task_lists}


def _batch_table(batch: dict[str, Any], names: dict[str, str]) -> Table:
    counts = ", ".join(f"{k} {v}" for k, v in sorted(batch["counts"].items()))
    table = Table(title=f"batch {batch['id']}  {batch['progress']:.1f}%  ({counts})")
    for col in ("job", "scene", "tasks", "state", "stage", "progress"):
        table.add_column(col)
    for job in batch["jobs"]:
        style = {"succeeded": "green", "failed": "red", "cancelled": "yellow"}.get(job["state"], "")
        table.add_row(job["id"], names.get(job["scene_id"], job["scene_id"]), "; ".join(job["tasks"])[:60],
                      f"[{style}]{job['state']}[/]" if style else job["state"], job["stage"] or "",
                      f"{job['progress']:.0f}%")  # fmt: skip
    return table


def batch(manifest: str | Path, *, server: str | None = None, api_key: str | None = None, wait: bool = True,
          out: str | Path | None = None, poll_s: float = 1.0) -> int:  # fmt: skip
    """Upload the manifest's scenes, submit scenes x task lists, show a live table of job states."""
    path = Path(manifest)
    spec = _manifest(path)
    names: dict[str, str] = {}
    with _client(server or spec.get("server"), api_key) as client:
        scene_ids = []
        for entry in spec["scenes"]:
            entry = str(entry)
            if entry.startswith("s_"):
                scene_ids.append(client.scene(entry)["id"])
                continue
            folder = (path.parent / entry).resolve()
            scene = _upload(client, folder)
            names[scene["id"]] = folder.name
            scene_ids.append(scene["id"])
        body = {"scene_ids": scene_ids, "task_lists": spec["task_lists"],
                "parameters": spec.get("parameters") or {}, "model_profile": spec.get("model_profile", "default")}  # fmt: skip
        state = client.submit_batch(body)
        print(state["id"])
        if not wait:
            return 0
        with Live(_batch_table(state, names), console=console, refresh_per_second=4) as live:
            while not state["finished"]:
                time.sleep(poll_s)
                state = client.batch(state["id"])
                live.update(_batch_table(state, names))
        if out is not None:
            for job in state["jobs"]:
                if job["state"] == "succeeded":
                    client.download_artifacts(job["id"], Path(out) / job["id"])
        failed = [j for j in state["jobs"] if j["state"] != "succeeded"]
        return 0 if not failed else 1


# ---- argparse wiring ---------------------------------------------------------------------------


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--server", help=f"API base URL (default: $BFIELDS_SERVER or {DEFAULT_SERVER})")
    p.add_argument("--api-key", help="API key (default: $BFIELDS_API_KEY)")


def _run(fn: Any, **kwargs: Any) -> int:
    try:
        return fn(**kwargs)
    except (ClientError, InputError) as exc:
        console.print(f"[red]error:[/] {exc}")
        return 2


def register_client_commands(subparsers: argparse._SubParsersAction) -> None:
    """Add submit/status/fetch/batch to a `bfields` argparse parser (handler in `func`)."""
    p = subparsers.add_parser("submit", help="upload a scene folder and submit a job to the service")
    p.add_argument("scene_dir")
    p.add_argument("--tasks", required=True, help="task list (.yaml, .json or one task per line)")
    p.add_argument("--parameters", help="YAML/JSON mapping of pipeline parameters")
    p.add_argument("--wait", action="store_true", help="poll until the job ends (exit 1 unless it succeeded)")
    _common(p)
    p.set_defaults(func=lambda a: _run(submit, scene_dir=a.scene_dir, tasks_file=a.tasks, server=a.server,
                                       api_key=a.api_key, wait=a.wait, parameters=a.parameters))  # fmt: skip

    p = subparsers.add_parser("status", help="show a job's state, stage, progress and timings")
    p.add_argument("job_id")
    _common(p)
    p.set_defaults(func=lambda a: _run(status, job_id=a.job_id, server=a.server, api_key=a.api_key))

    p = subparsers.add_parser("fetch", help="download every artifact of a finished job")
    p.add_argument("job_id")
    p.add_argument("--out", required=True, help="output folder")
    _common(p)
    p.set_defaults(func=lambda a: _run(fetch, job_id=a.job_id, out=a.out, server=a.server, api_key=a.api_key))

    p = subparsers.add_parser("batch", help="run many scenes x task lists from a YAML manifest")
    p.add_argument("manifest")
    p.add_argument("--out", help="download the results of succeeded jobs here")
    p.add_argument("--no-wait", action="store_true", help="submit and print the batch id only")
    _common(p)
    p.set_defaults(func=lambda a: _run(batch, manifest=a.manifest, server=a.server, api_key=a.api_key,
                                       wait=not a.no_wait, out=a.out))  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m bayesian_fields_service.client``) with the same sub-commands."""
    parser = argparse.ArgumentParser(prog="bfields-client")
    register_client_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
