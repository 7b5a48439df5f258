"""`bfields submit | status | fetch | batch`: the service from the command line.

`register_client_commands(subparsers)` adds the four sub-commands to the `bfields` argparse
parser; each handler is also a plain function (`submit`, `status`, `fetch`, `batch`) returning an
exit code. The server comes from ``--server`` or ``BFIELDS_SERVER``, the key from ``--api-key``
or ``BFIELDS_API_KEY`` (so it stays out of shell history).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from rich.progress import (
    BarColumn,
    DownloadColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeRemainingColumn,
    TransferSpeedColumn,
)

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
           wait: bool = False, parameters: str | None = None, poll_s: float = 1.0,
           priority: str = "interactive") -> int:  # fmt: skip
    """Upload a scene folder, submit a job for the task list; with `wait`, poll until it ends.
    A 429 / 503 is retried after the server's Retry-After (bounded); the submission carries one
    Idempotency-Key across those retries, so it never makes two jobs."""
    tasks = load_tasks(tasks_file)
    with _client(server, api_key) as client:
        scene = _upload(client, Path(scene_dir))
        console.print(f"scene {scene['id']}: {scene['summary'].get('frames')} frames, "
                      f"{scene['summary'].get('gaussians')} Gaussians")  # fmt: skip
        job = client.submit_job(scene["id"], tasks, parameters=_parameters(parameters),
                                idempotency_key=str(uuid.uuid4()), priority=priority)  # fmt: skip
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


def item_key(scene: str, tasks: list[str], parameters: dict[str, Any], model_profile: str) -> str:
    """The Idempotency-Key of one manifest item, derived from what the item asks for (the scene
    entry as written in the manifest, resolved when it is a folder; tasks; parameters; model
    profile): re-running a manifest sends the same keys, so the server makes no new job."""
    blob = json.dumps({"scene": scene, "tasks": tasks, "parameters": parameters, "model_profile": model_profile},
                      sort_keys=True, ensure_ascii=True)  # fmt: skip
    return "bfields-item-" + hashlib.sha256(blob.encode()).hexdigest()[:40]


def _counts(state: dict[str, Any]) -> str:
    c = state["counts"]
    return "  ".join(
        f"{k} {c[k]}" for k in ("succeeded", "failed", "cancelled", "running", "queued") if c.get(k)
    )


def _follow(client: BFieldsClient, state: dict[str, Any], poll_s: float) -> dict[str, Any]:
    """A progress bar of finished jobs out of the batch, with per-state counts and an ETA."""
    total = state["total"] or len(state["jobs"])
    with Progress(TextColumn(f"batch {state['id']}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[counts]}"), TimeRemainingColumn(), console=console) as bar:  # fmt: skip
        task = bar.add_task("batch", total=total, counts="")
        while True:
            done = sum(state["counts"].get(k, 0) for k in ("succeeded", "failed", "cancelled"))
            bar.update(task, completed=done, counts=_counts(state))
            if state["finished"]:
                return state
            time.sleep(poll_s)
            state = client.batch(state["id"], jobs=False)


def batch(manifest: str | Path, *, server: str | None = None, api_key: str | None = None, wait: bool = True,
          out: str | Path | None = None, poll_s: float = 2.0, priority: str = "bulk") -> int:  # fmt: skip
    """Upload the manifest's scenes, submit scenes x task lists as one batch, follow it with a
    progress bar. Every item carries an Idempotency-Key derived from the item (`item_key`) and
    the batch one derived from the whole body, so a re-run manifest (after a crash, a 429 that ran
    out of retries, a Ctrl-C) creates no job twice."""
    path = Path(manifest)
    spec = _manifest(path)
    parameters = spec.get("parameters") or {}
    model_profile = spec.get("model_profile", "default")
    with _client(server or spec.get("server"), api_key) as client:
        items = []
        for entry in spec["scenes"]:
            entry = str(entry)
            if entry.startswith("s_"):
                scene_id, where = client.scene(entry)["id"], entry
            else:
                folder = (path.parent / entry).resolve()
                scene_id, where = _upload(client, folder)["id"], str(folder)
            for tasks in spec["task_lists"]:
                key = item_key(where, tasks, parameters, model_profile)
                items.append({"scene_id": scene_id, "tasks": tasks, "idempotency_key": key})
        body = {
            "items": items,
            "parameters": parameters,
            "model_profile": model_profile,
            "priority": priority,
        }
        # the batch's key names the whole body (an Idempotency-Key stands for one request): the same
        # manifest, scenes and priority again is the same batch; anything else a new batch, whose
        # unchanged items still reuse their jobs through their own keys
        batch_key = (
            "bfields-batch-"
            + hashlib.sha256(json.dumps(body, sort_keys=True, ensure_ascii=True).encode()).hexdigest()[:40]
        )
        state = client.submit_batch(body, idempotency_key=batch_key)
        print(state["id"])
        console.print(f"batch {state['id']}: {state['total']} jobs, {state['created']} new")
        if not wait:
            return 0
        state = _follow(client, state, poll_s)
        jobs = list(client.batch_jobs(state["id"]))
        if out is not None:
            for job in jobs:
                if job["state"] == "succeeded":
                    client.download_artifacts(job["id"], Path(out) / job["id"])
        failed = [j for j in jobs if j["state"] != "succeeded"]
        for j in failed[:20]:
            console.print(f"[red]{j['id']}[/] {j['state']}: {j['error'] or ''}")
        return 0 if not failed else 1


# ---- argparse wiring ---------------------------------------------------------------------------


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--server", help=f"API base URL (default: $BFIELDS_SERVER or {DEFAULT_SERVER})")
    p.add_argument("--api-key", help="API key (default: $BFIELDS_API_KEY)")


def _priority(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument("--priority", choices=("interactive", "bulk"), default=default,
                   help=f"class in your fair-share queue: interactive jobs go first (default: {default})")  # fmt: skip


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
    _priority(p, "interactive")
    _common(p)
    p.set_defaults(func=lambda a: _run(submit, scene_dir=a.scene_dir, tasks_file=a.tasks, server=a.server,
                                       api_key=a.api_key, wait=a.wait, parameters=a.parameters,
                                       priority=a.priority))  # fmt: skip

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
    _priority(p, "bulk")
    _common(p)
    p.set_defaults(func=lambda a: _run(batch, manifest=a.manifest, server=a.server, api_key=a.api_key,
                                       wait=not a.no_wait, out=a.out, priority=a.priority))  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m bayesian_fields_service.client``) with the same sub-commands."""
    parser = argparse.ArgumentParser(prog="bfields-client")
    register_client_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
