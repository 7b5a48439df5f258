"""`bfields submit | status | fetch | batch`: what the client verbs do.

Each is a plain function (`submit`, `status`, `fetch`, `batch`) returning an exit code; their
arguments are wired in `verbs` (which imports this module only when a verb runs: it imports
httpx and rich). The server comes from ``--server`` or ``BFIELDS_SERVER``, the key from ``--api-key``
or ``BFIELDS_API_KEY`` (so it stays out of shell history).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from rich.progress import (
    BarColumn,
    DownloadColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeRemainingColumn,
    TransferSpeedColumn,
)

from bayesian_fields_core.cli.job_options import parameter_overrides, resolve_tasks, validate_parameters
from bayesian_fields_core.cli.output import message_console
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.task_list import load_tasks, normalise_tasks
from bayesian_fields_service.client.api import BFieldsClient, ClientError
from bayesian_fields_service.client.defaults import DEFAULT_SERVER

console = message_console(stderr=True)


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


def submit(scene_dir: str | Path, tasks_file: str | Path | None = None, *, task: Sequence[str] = (),
           server: str | None = None, api_key: str | None = None, wait: bool = False,
           parameters: str | Path | None = None, param: Sequence[str] = (), poll_s: float = 1.0,
           priority: str = "interactive") -> int:  # fmt: skip
    """Upload a scene folder, submit a job for its tasks; with `wait`, poll until it ends.

    The tasks and parameters are read as `bfields run` reads them (`job_options`): `task` texts,
    else the `tasks_file`, else the scene's tasks.yaml; the `parameters` file (a YAML mapping)
    with each `param` NAME=VALUE over it, checked here before anything is uploaded. A 429 / 503 is
    retried after the server's Retry-After (bounded); the submission carries one Idempotency-Key
    across those retries, so it never makes two jobs."""
    tasks = resolve_tasks(task, None if tasks_file is None else str(tasks_file), Path(scene_dir))
    overrides = parameter_overrides(None if parameters is None else str(parameters), param)
    validate_parameters(overrides)
    with _client(server, api_key) as client:
        scene = _upload(client, Path(scene_dir))
        console.print(f"scene {scene['id']}: {scene['summary'].get('frames')} frames, "
                      f"{scene['summary'].get('gaussians')} Gaussians")  # fmt: skip
        job = client.submit_job(scene["id"], tasks, parameters=overrides,
                                idempotency_key=str(uuid.uuid4()), priority=priority)  # fmt: skip
        print(job["id"])
        if not wait:
            return 0
        final = _wait_with_bar(client, job["id"], poll_s)
        console.print(
            f"job {final['id']} {final['state']}" + (f": {final['error']}" if final["error"] else "")
        )
        return 0 if final["state"] == "succeeded" else 1


SUPERSEDED_FIELDS = ("attempts",)
"""Fields of a job record the API still sends for older clients under a former name (`attempts`
is `stage_runs`); `bfields status` does not show them."""


def status(job_id: str, *, server: str | None = None, api_key: str | None = None) -> int:
    """Print a job's record as JSON (without the superseded names)."""
    with _client(server, api_key) as client:
        job = client.job(job_id)
    _print({k: v for k, v in job.items() if k not in SUPERSEDED_FIELDS})
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
    total = state["total"]
    with Progress(TextColumn(f"batch {state['id']}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[counts]}"), TimeRemainingColumn(), console=console) as bar:  # fmt: skip
        task = bar.add_task("batch", total=total, counts="")
        while True:
            done = sum(state["counts"].get(k, 0) for k in ("succeeded", "failed", "cancelled"))
            bar.update(task, completed=done, counts=_counts(state))
            if state["finished"]:
                return state
            time.sleep(poll_s)
            state = client.batch(state["id"])


def batch(manifest: str | Path, *, server: str | None = None, api_key: str | None = None, wait: bool = True,
          out: str | Path | None = None, poll_s: float = 2.0, priority: str = "bulk",
          params: str | Path | None = None, param: Sequence[str] = ()) -> int:  # fmt: skip
    """Upload the manifest's scenes, submit scenes x task lists as one batch, follow it with a
    progress bar. Every item carries an Idempotency-Key derived from the item (`item_key`) and
    the batch one derived from the whole body, so a re-run manifest (after a crash, a 429 that ran
    out of retries, a Ctrl-C) creates no job twice. `params` (a YAML mapping) and `param`
    (NAME=VALUE) go over the manifest's `parameters`, as `bfields run` reads them."""
    path = Path(manifest)
    spec = _manifest(path)
    parameters = {
        **(spec.get("parameters") or {}),
        **parameter_overrides(None if params is None else str(params), param),
    }
    validate_parameters(parameters)
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


def answers(batch_id: str | None, *, everything: bool = False, task: str | None = None,
            min_probability: float | None = None, fmt: str = "table", out: str | None = None,
            server: str | None = None, api_key: str | None = None) -> int:  # fmt: skip
    """`bfields answers`: a batch's or the fleet's answers as one table (`client.answers`)."""
    from bayesian_fields_service.client.answers import answers as show
    from bayesian_fields_service.client.answers import check

    check(batch_id, everything=everything, task=task, fmt=fmt)
    with _client(server, api_key) as client:
        return show(client, batch_id, everything=everything, task=task, min_probability=min_probability,
                    fmt=fmt, out=out)  # fmt: skip


def run_verb(fn: Any, **kwargs: Any) -> int:
    """Call a client verb; a client or input error is one red line and exit status 2."""
    try:
        return fn(**kwargs)
    except (ClientError, InputError) as exc:
        console.print(f"[red]error:[/] {' '.join(str(exc).split())}", soft_wrap=True)
        return 2


_run = run_verb  # the name tests and older callers use
