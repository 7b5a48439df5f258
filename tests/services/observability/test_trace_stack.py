"""One connected trace per job through the real stack (issue 44, tracing and JSON logs).

The sample scene (`samples/tabletop`) runs as two jobs through a private stack: the API
(uvicorn), the control process and a Celery worker per queue (the GPU queue's with the
production prefork pool, so a forked pool child's spans are seen too), on PostgreSQL, Redis and
the S3 server, every process with ``BFIELDS_TRACING=file:<spans>`` and ``BFIELDS_LOG_FORMAT=json``.
Read back from the spans file, each job is one trace: its root is the submission request's span,
every parent resolves inside it, the control process's dispatch span hangs from the root (through
the traceparent on the job's row), and the three stages (with their frame, mask and Gaussian
counts), their Celery tasks and the SQL, S3 and Redis calls are under it. The processes' log lines
are JSON, and a stage's lines carry the job, tenant, stage and trace ids.

Measured here: the module in 50-100 s on the shared 2-core machine at a load average of 12-20
(the stack's start included). ``-s`` prints the first job's span tree (the one in docs/operations/tracing-and-logs.md).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.services.conftest import scene_form
from tests.services.observability.span_trees import Span, ancestors, read_spans, render, roots, trace_spans
from tests.services.support.private_stack import PrivateStack, wait_job

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"
TASKS = [str(t["task"]) for t in yaml.safe_load((SAMPLE / "tasks.yaml").read_text())["tasks"]]
STAGES = ("perceive", "fuse", "cluster")


@pytest.fixture(scope="module")
def traced(
    private_stacks: Callable[[str, Mapping[str, str]], PrivateStack], tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Any]:
    """The stack with tracing to a file and JSON logs, the sample uploaded, two jobs run."""
    spans = tmp_path_factory.mktemp("spans") / "spans.jsonl"
    stack = private_stacks(
        "trace-stack", {"BFIELDS_TRACING": f"file:{spans}", "BFIELDS_LOG_FORMAT": "json"}
    ).start()
    assert stack.api is not None and stack.pool is not None
    workers = [stack.pool.start("gpu", pool="prefork"), stack.pool.start("cpu")]
    folder = tmp_path_factory.mktemp("sample") / "tabletop"
    shutil.copytree(SAMPLE, folder)
    (folder / "splat.ply").symlink_to(folder / "point_cloud.ply")  # the name `scene_form` sends
    with stack.api.client("tenant-a") as client:
        resp = client.post("/v1/scenes", files=scene_form(folder), data={"name": "tabletop"})
        assert resp.status_code == 201, resp.text
        scene_id = resp.json()["id"]
        jobs = []
        for _ in range(2):
            resp = client.post(
                "/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": {"max_frames": 4}}
            )
            assert resp.status_code == 202, resp.text
            jobs.append(wait_job(client, resp.json()["id"]))
    assert [j["state"] for j in jobs] == ["succeeded", "succeeded"], jobs
    assert "traceparent" not in jobs[0]  # kept on the row, never shown to clients
    return {
        "stack": stack,
        "spans": _settled(spans, [j["id"] for j in jobs]),
        "jobs": jobs,
        "workers": workers,
    }


def _settled(path: Path, job_ids: list[str], timeout_s: float = 30) -> list[Span]:
    """The spans file once every job's trace is whole: a span is written when it ends, and a
    task's span ends a moment after the job's row says succeeded. The last read at the deadline
    otherwise (the test's assertions then say what is missing)."""
    deadline = time.monotonic() + timeout_s
    while True:
        spans = read_spans(path)
        whole = True
        for job_id in job_ids:
            traces = {s["trace_id"] for s in spans if s["attributes"].get("bfields.job_id") == job_id}
            trace = trace_spans(spans, traces.pop()) if len(traces) == 1 else []
            ids = {s["span_id"] for s in trace}
            whole &= bool(trace) and all(s["parent_id"] is None or s["parent_id"] in ids for s in trace)
        if whole or time.monotonic() > deadline:
            return spans
        time.sleep(0.2)


def _job_trace(spans: list[Span], job_id: str) -> list[Span]:
    """The spans of the trace the job's stage spans belong to (exactly one trace)."""
    traces = {s["trace_id"] for s in spans if s["attributes"].get("bfields.job_id") == job_id}
    assert len(traces) == 1, f"job {job_id} is in {len(traces)} traces"
    return trace_spans(spans, traces.pop())


def test_each_job_is_one_connected_trace(traced: dict[str, Any]) -> None:
    spans, jobs = traced["spans"], traced["jobs"]
    trace_ids = set()
    for job in jobs:
        trace = _job_trace(spans, job["id"])
        trace_ids.add(trace[0]["trace_id"])
        (root,) = roots(trace)
        assert root["name"] == "POST /v1/jobs" and root["service"] == "bfields-api", root
        ids = {s["span_id"] for s in trace}
        assert all(s["parent_id"] in ids for s in trace if s is not root)  # every parent resolves
        assert {s["service"] for s in trace} == {"bfields-api", "bfields-control", "bfields-worker"}
        (dispatch,) = [s for s in trace if s["name"] == "dispatch"]
        assert dispatch["parent_id"] == root["span_id"] and dispatch["service"] == "bfields-control"
        assert dispatch["attributes"]["bfields.job_id"] == job["id"]
        stage_spans = {s["attributes"]["bfields.stage"]: s for s in trace if s["name"].startswith("stage ")}
        assert set(stage_spans) == set(STAGES)
        for stage, span in stage_spans.items():
            path = ancestors(trace, span)
            assert path[-1] == "POST /v1/jobs" and "dispatch" in path, (stage, path)
            assert any(name.startswith("run/") for name in path), path  # under its Celery task's span
        perceive, fuse, cluster = (stage_spans[s]["attributes"] for s in STAGES)
        assert perceive["bfields.frames"] == 4
        assert fuse["bfields.frames"] == 4 and fuse["bfields.masks"] > 0
        assert fuse["bfields.gaussians"] == job["stage_reports"]["fuse"]["gaussians"] > 0
        assert cluster["bfields.objects"] >= 1
        # the calls below the stages: SQL (the job's row), S3 (the artifacts), Redis (progress)
        assert any(s["attributes"].get("db.system") == "postgresql" for s in trace)
        assert any(s["attributes"].get("rpc.service") == "S3" for s in trace)
        assert any(s["attributes"].get("db.system") == "redis" for s in trace)
    assert len(trace_ids) == len(jobs)  # one trace per job
    # the second job reused the first's perception: its perceive span says so
    second = _job_trace(spans, jobs[1]["id"])
    (perceive,) = [s for s in second if s["name"] == "stage perceive"]
    assert perceive["attributes"]["bfields.frames_cached"] == 4
    print("\n" + render(_job_trace(spans, jobs[0]["id"])))


def _json_lines(text: str) -> list[dict[str, Any]]:
    """The log's lines from its first record on (the test's start line and Celery's banner,
    printed before its logging starts, are not records); each must parse as JSON."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("{")), len(lines))
    return [json.loads(line) for line in lines[start:] if line.strip() and not line.startswith(" ")]


def test_every_process_logs_json_lines_with_the_job_and_trace(traced: dict[str, Any]) -> None:
    stack: PrivateStack = traced["stack"]
    job_id = traced["jobs"][0]["id"]
    trace_id = _job_trace(traced["spans"], job_id)[0]["trace_id"]
    assert stack.api is not None
    api_lines = _json_lines((stack.api.log_dir / "api.log").read_text())
    assert any(line["logger"] == "uvicorn.access" and "/v1/jobs" in line["message"] for line in api_lines)
    control_lines = _json_lines((stack.api.log_dir / "control.log").read_text())
    assert any(line["message"].startswith("control process ready") for line in control_lines)
    worker_lines = [line for w in traced["workers"] for line in _json_lines(w.log_text())]
    for line in api_lines + control_lines + worker_lines:
        assert {"time", "level", "logger", "message"} <= set(line), line
    staged = [line for line in worker_lines if line.get("job_id") == job_id]
    assert {line["stage"] for line in staged} >= {"perceive", "cluster"}, staged
    assert all(line["tenant"] == "tenant-a" and line["trace_id"] == trace_id for line in staged), staged
