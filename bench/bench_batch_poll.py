"""Another tenant's latency while one tenant polls a fleet-sized batch (issue 41, item 5).

Issue 41 measured tenant B's `GET /v1/jobs` p99 at 0.05 s idle and 11.2 s while tenant A polled its
20,000-job batch's `GET /v1/batches/{id}` from 20 threads: that answer listed every job (3.6 MB,
~52 s each). The answer is the aggregate now (counts and progress, a few reads whatever the size);
`jobs=true` lists jobs only up to `BFIELDS_BATCH_JOBS_INLINE_MAX`.

The bench starts its own stack (`bench_batch_ops.batch_stack`: private Redis, `rclone serve s3`, a
PostgreSQL database of its own, one uvicorn API with its bulk lane and the control process, no
workers: every job waits), uploads one tiny scene, submits one batch of `--size` jobs as tenant A,
then runs tenant B's probe (bench/latency_probe.py, a process of its own) for `--idle-s` with
nothing else going on, and for `--poll-s` while `--threads` threads of A poll the batch without a
pause (or `--pause-s` between polls, as a client's poll interval). It prints B's p50 / p99 idle and
during the polling, their ratio (goal: p99 within 2x), and A's polls per second and median poll time.

`--list-jobs` measures the old behaviour for comparison: the bound raised to the batch's size and
A polling with `jobs=true` (every job in every answer).

`--tenant-concurrency N` sets the API's per-tenant bound (BFIELDS_API_TENANT_CONCURRENCY; the
API's fairness gate, docs/service/api.md "Fairness between tenants") to compare bounds.

    python -m bench.bench_batch_poll --size 20000
    python -m bench.bench_batch_poll --size 20000 --tenant-concurrency 1
    python -m bench.bench_batch_poll --size 5000 --list-jobs
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from bench.bench_batch_ops import _client, _ok, _pct, _start_probe, batch_stack


def _poll(stack: Any, batch_id: str, params: dict[str, str], until: float, pause_s: float,
          took: list[float], refused: list[float]) -> None:  # fmt: skip
    """Poll as a client that honours the API's 429s does (the project's client waits Retry-After):
    each answered poll's time goes to `took`, each 429's Retry-After to `refused`."""
    with _client(stack, "tenant-a", 600) as client:
        while time.monotonic() < until:
            t0 = time.monotonic()
            resp = client.get(f"/v1/batches/{batch_id}", params=params)
            if resp.status_code == 429:
                wait_s = float(resp.headers.get("Retry-After", "1"))
                refused.append(wait_s)
                time.sleep(min(wait_s, max(until - time.monotonic(), 0.0)))
                continue
            _ok(resp)
            took.append(time.monotonic() - t0)
            time.sleep(pause_s)


def measure(stack: Any, batch_id: str, args: argparse.Namespace) -> dict[str, Any]:
    """B's latency idle, then while A's threads poll the batch (each sample placed by its start)."""
    params = {"jobs": "true"} if args.list_jobs else {}
    probe = _start_probe(stack)
    polls: list[float] = []
    refusals: list[float] = []
    try:
        idle_from = time.monotonic()
        time.sleep(args.idle_s)
        busy_from = time.monotonic()
        until = busy_from + args.poll_s
        threads = [threading.Thread(target=_poll, args=(stack, batch_id, params, until, args.pause_s, polls, refusals))
                   for _ in range(args.threads)]  # fmt: skip
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        busy_to = time.monotonic()
    finally:
        out, _ = probe.communicate("", timeout=300)
    samples = [(float(a), float(b)) for a, b in (line.split() for line in out.splitlines())]
    idle = [t for s, t in samples if idle_from <= s and s + t <= busy_from]
    busy = [t for s, t in samples if busy_from <= s < busy_to]
    figures = {
        "idle_p50_s": _pct(idle, 0.5), "idle_p99_s": _pct(idle, 0.99), "idle_n": len(idle),
        "busy_p50_s": _pct(busy, 0.5), "busy_p99_s": _pct(busy, 0.99), "busy_n": len(busy),
        "polls": len(polls), "poll_median_s": statistics.median(polls) if polls else None,
        "polls_per_s": len(polls) / max(busy_to - busy_from, 1e-9),
        "refused_429": len(refusals),
    }  # fmt: skip
    figures["p99_ratio"] = figures["busy_p99_s"] / figures["idle_p99_s"]
    return figures


def _default_rate() -> float:
    from bayesian_fields_service.config.settings import ServiceSettings

    return float(ServiceSettings.model_fields["api_tenant_rate"].default)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=20_000, help="jobs in tenant A's batch")
    parser.add_argument("--threads", type=int, default=20, help="tenant A's polling threads")
    parser.add_argument("--idle-s", type=float, default=15.0)
    parser.add_argument("--poll-s", type=float, default=30.0)
    parser.add_argument("--pause-s", type=float, default=0.0,
                        help="each thread's pause between polls (0: back to back; `bfields batch` waits 2 s)")  # fmt: skip
    parser.add_argument("--list-jobs", action="store_true",
                        help="the old behaviour: jobs=true with the bound raised to --size")  # fmt: skip
    parser.add_argument("--tenant-concurrency", type=int,
                        help="BFIELDS_API_TENANT_CONCURRENCY of the API (unset: the setting's default)")  # fmt: skip
    parser.add_argument("--rate", type=float,
                        help="BFIELDS_API_TENANT_RATE of the API (unset: the setting's default; 0: no rate bound)")  # fmt: skip
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()

    from tests.services.support.private_stack import upload
    from tests.services.support.scene_factory import make_scene

    env = {"BFIELDS_BATCH_JOBS_INLINE_MAX": str(args.size)} if args.list_jobs else {}
    if args.tenant_concurrency is not None:
        env["BFIELDS_API_TENANT_CONCURRENCY"] = str(args.tenant_concurrency)
    # the stack's test environment turns the rate off; the bench measures the setting's default
    env["BFIELDS_API_TENANT_RATE"] = str(args.rate if args.rate is not None else _default_rate())
    with (
        tempfile.TemporaryDirectory(prefix="bench-batch-poll-") as tmp,
        batch_stack(Path(tmp), args.size, env=env) as stack,
    ):
        scene_id = upload(_client(stack, "tenant-a", 120), make_scene(Path(tmp) / "scene"))
        items = [{"scene_id": scene_id, "tasks": [f"poll {i}"]} for i in range(args.size)]
        t0 = time.monotonic()
        with _client(stack, "tenant-a", 1200) as client:
            batch = _ok(client.post("/v1/batches", json={"items": items})).json()
            print(f"batch of {args.size} jobs submitted in {time.monotonic() - t0:.1f} s")
            size_b = len(_ok(client.get(f"/v1/batches/{batch['id']}",
                                        params={"jobs": "true"} if args.list_jobs else {})).content)  # fmt: skip
        figures = measure(stack, batch["id"], args)
        figures.update(size=args.size, threads=args.threads, list_jobs=args.list_jobs, answer_bytes=size_b,
                       tenant_concurrency=args.tenant_concurrency, rate=env["BFIELDS_API_TENANT_RATE"],
                       load_1min=os.getloadavg()[0])  # fmt: skip
        with _client(stack, "tenant-a", 600) as client:
            _ok(client.post(f"/v1/batches/{batch['id']}/cancel"))
    mode = "jobs=true (old default)" if args.list_jobs else "aggregate (default)"
    print(f"tenant A: {args.threads} threads (pause {args.pause_s:g} s) polling GET /v1/batches/{{id}} of {args.size} jobs, {mode}: "
          f"{figures['answer_bytes']:,} bytes per answer, {figures['polls_per_s']:.1f} polls/s, "
          f"median {figures['poll_median_s']:.3f} s; {figures['refused_429']} answered 429 "
          f"(BFIELDS_API_TENANT_RATE={env['BFIELDS_API_TENANT_RATE']})")  # fmt: skip
    print(f"tenant B GET /v1/jobs   idle: p50 {figures['idle_p50_s']:.3f} s  p99 {figures['idle_p99_s']:.3f} s "
          f"(n={figures['idle_n']})")  # fmt: skip
    print(f"tenant B GET /v1/jobs polled: p50 {figures['busy_p50_s']:.3f} s  p99 {figures['busy_p99_s']:.3f} s "
          f"(n={figures['busy_n']})")  # fmt: skip
    print(f"p99 ratio (polled / idle): {figures['p99_ratio']:.2f}x (goal: within 2x); "
          f"1-min load {figures['load_1min']:.1f}")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
