"""Fleet operations on a real stack (issue 28, item 2): submit, status, a page and cancel of one
large batch, and what another tenant's requests cost meanwhile.

The bench starts its own stack (a private redis-server, `rclone serve s3`, a PostgreSQL database of
its own on the machine's server, one uvicorn API; no workers, so every job only waits, as in the
issue's measurement) and uploads one tiny synthetic scene. For each size and each of `--repeats`
rounds it:

- submits one batch of that many items (`POST /v1/batches`, every item the scene with its own task
  and, as `bfields batch` sends them, an Idempotency-Key per item and one for the batch)
  -> `submit_s`;
- reads its status without the job list (`GET /v1/batches/{id}?jobs=false`) -> `status_s`;
- reads a page of 100 jobs from the middle of the batch (`GET /v1/batches/{id}/jobs`) -> `page_s`;
- cancels it (`POST /v1/batches/{id}/cancel`) -> `cancel_s`.

Figures are medians over the rounds (status and page: the median of 5 reads per round, then of the
rounds). `--other-tenant` also measures tenant B's `GET /v1/jobs?limit=20` latency, idle and while
A submits a batch of up to 5,000 (five times, for enough samples), from a probe process of its
own (bench/latency_probe.py), and prints the p50 / p99 of each; with `--api-processes 2` tenant B is
served by a second API process on the same records (two replicas behind a balancer), as a
deployment that sizes its API for fleet submissions would run it. The control process runs beside
the API (its dispatcher sends up to the dispatch bound of each tenant's jobs to a queue no worker
reads; they stay queued and are cancelled with the rest). Batches are served by each API process's
bulk lane (docs/service/records.md), or inside the API process with `--no-bulk-lane`.

The machine's 1-minute load average is printed with each size. Usage (repository root):

    python -m bench.bench_batch_ops --sizes 100,1000,5000
    python -m bench.bench_batch_ops --sizes 5000,50000 --json bench/results/batch-ops.json --other-tenant
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx

KEYS = {"tenant-a": "key-a", "tenant-b": "key-b"}  # tenant -> API key
PAGE = 100


@contextmanager
def batch_stack(
    workdir: Path, max_batch: int, api_processes: int = 1, bulk_lane: bool = True,
    env: dict[str, str] | None = None,
) -> Iterator[Any]:  # fmt: skip
    """Redis + S3 + PostgreSQL database + one API (and its control process), no workers (jobs only
    wait); with `api_processes` 2, a second API process on the same records (`stack.other_api`);
    `env`: more settings of the stack's processes. The S3 server is `stack.s3`."""
    from tests.integration.fixtures.s3_server import S3Server
    from tests.integration.fixtures.services import ApiServer
    from tests.services.support.private_stack import PrivateStack

    extra = {
        "BFIELDS_MAX_BATCH_JOBS": str(max_batch),
        "BFIELDS_MAX_WAITING_JOBS_PER_TENANT": str(4 * max_batch),
        "BFIELDS_API_BULK_LANE": "true" if bulk_lane else "false",
        **(env or {}),
    }
    s3 = S3Server(workdir / "s3").start()
    stack = PrivateStack(workdir, s3.env(), dict(KEYS), extra)
    other = None
    try:
        stack.start()
        stack.s3 = s3  # type: ignore[attr-defined]
        stack.other_api = stack.api  # type: ignore[attr-defined]
        if api_processes > 1:
            other = ApiServer(env=stack.env, log_dir=workdir / "api2", keys=dict(KEYS), control=False).start()
            stack.other_api = other  # type: ignore[attr-defined]
        yield stack
    finally:
        if other is not None:
            other.stop()
        stack.stop()
        s3.stop()


def _client(stack: Any, tenant: str, timeout_s: float, *, other: bool = False) -> httpx.Client:
    api = stack.other_api if other else stack.api
    return httpx.Client(base_url=api.base_url, headers=api.headers(tenant), timeout=timeout_s)


def _timed(fn: Callable[[], httpx.Response]) -> tuple[float, httpx.Response]:
    t0 = time.perf_counter()
    resp = fn()
    return time.perf_counter() - t0, resp


def _ok(resp: httpx.Response) -> httpx.Response:
    if resp.status_code >= 400:
        raise SystemExit(
            f"{resp.request.method} {resp.request.url.path}: {resp.status_code} {resp.text[:300]}"
        )
    return resp


def one_round(client: httpx.Client, scene_id: str, size: int, tag: str) -> dict[str, float]:
    # as `bfields batch` sends them: an Idempotency-Key per item and one for the batch
    items = [
        {"scene_id": scene_id, "tasks": [f"{tag} task {i}"], "idempotency_key": f"bench-{tag}-{i}"}
        for i in range(size)
    ]
    submit_s, resp = _timed(
        lambda: client.post(
            "/v1/batches", json={"items": items}, headers={"Idempotency-Key": f"bench-batch-{tag}"}
        )
    )
    batch = _ok(resp).json()
    assert batch["total"] == size and batch["created"] == size, batch
    batch_id = batch["id"]

    status = []
    for _ in range(5):
        dt, resp = _timed(lambda: client.get(f"/v1/batches/{batch_id}", params={"jobs": "false"}))
        assert _ok(resp).json()["total"] == size
        status.append(dt)

    # the cursor of the middle page: walk there once (untimed), then time reads of that page
    cursor: str | None = None
    for _ in range(size // PAGE // 2):
        cursor = _ok(client.get(f"/v1/batches/{batch_id}/jobs",
                                params={"limit": PAGE, **({"cursor": cursor} if cursor else {})})).json()["next_cursor"]  # fmt: skip
    pages = []
    params: dict[str, Any] = {"limit": PAGE, **({"cursor": cursor} if cursor else {})}
    for _ in range(5):
        dt, resp = _timed(lambda: client.get(f"/v1/batches/{batch_id}/jobs", params=params))
        assert len(_ok(resp).json()["items"]) == min(PAGE, size)
        pages.append(dt)

    cancel_s, resp = _timed(lambda: client.post(f"/v1/batches/{batch_id}/cancel"))
    counts = _ok(resp).json()["counts"]
    assert counts.get("cancelled", 0) == size, counts
    return {"submit_s": submit_s, "status_s": statistics.median(status),
            "page_s": statistics.median(pages), "cancel_s": cancel_s}  # fmt: skip


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def _start_probe(stack: Any) -> subprocess.Popen[str]:
    """Tenant B's probe (bench/latency_probe.py), a process of its own, on B's API process."""
    api = stack.other_api
    return subprocess.Popen(
        [sys.executable, "-m", "bench.latency_probe", api.base_url, KEYS["tenant-b"]],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parent.parent,
    )  # fmt: skip


def _overlaps(start: float, took: float, windows: list[tuple[float, float]]) -> bool:
    return any(start < w_end and start + took > w_start for w_start, w_end in windows)


def other_tenant(stack: Any, scene_id: str, size: int, rounds: int = 5) -> dict[str, float]:
    """Tenant B's listing latency idle (the first 10 s), then while tenant A submits a batch of
    `size`, `rounds` times (each batch cancelled after, with a pause). B's requests come from a
    probe process (bench/latency_probe.py says why); a request is "busy" when it overlaps one of
    A's submits (from A's send to A's decoded answer), and requests that overlap a cancel or a
    pause are not counted. One submit lasts about a second, so a round gives a dozen samples."""
    client_a = _client(stack, "tenant-a", 600)
    probe = _start_probe(stack)
    try:
        started = time.monotonic()
        time.sleep(10)
        idle_until = time.monotonic()
        windows: list[tuple[float, float]] = []
        for n in range(rounds):
            items = [{"scene_id": scene_id, "tasks": [f"other {n} {i}"]} for i in range(size)]
            w_start = time.monotonic()
            batch = _ok(client_a.post("/v1/batches", json={"items": items})).json()
            windows.append((w_start, time.monotonic()))
            _ok(client_a.post(f"/v1/batches/{batch['id']}/cancel"))
            time.sleep(1)
    finally:
        out, _ = probe.communicate("", timeout=120)
    if probe.returncode:
        raise RuntimeError(f"the latency probe failed (exit {probe.returncode})")
    samples = [(float(a), float(b)) for a, b in (line.split() for line in out.splitlines())]
    idle = [t for s, t in samples if started <= s and s + t <= idle_until]
    busy = [t for s, t in samples if _overlaps(s, t, windows)]
    return {"idle_p50_s": _pct(idle, 0.5), "idle_p99_s": _pct(idle, 0.99), "idle_n": len(idle),
            "busy_p50_s": _pct(busy, 0.5), "busy_p99_s": _pct(busy, 0.99), "busy_n": len(busy)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="100,1000,5000", help="comma-separated batch sizes")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, help="write the per-size medians here")
    parser.add_argument("--other-tenant", action="store_true", help="tenant B's latency during A's submit")
    parser.add_argument("--no-bulk-lane", action="store_true",
                        help="batches served inside the API process (BFIELDS_API_BULK_LANE=false), as before the lane")  # fmt: skip
    parser.add_argument("--api-processes", type=int, choices=(1, 2), default=1,
                        help="2: tenant B is served by a second API process")  # fmt: skip
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]

    from tests.services.support.private_stack import upload
    from tests.services.support.scene_factory import make_scene

    out: dict[str, Any] = {"sizes": {}, "repeats": args.repeats, "api_processes": args.api_processes,
                           "bulk_lane": not args.no_bulk_lane}  # fmt: skip
    with (
        tempfile.TemporaryDirectory(prefix="bench-batch-ops-") as tmp,
        batch_stack(Path(tmp), max(sizes), args.api_processes, not args.no_bulk_lane) as stack,
    ):
        client = _client(stack, "tenant-a", 1200)
        scene_id = upload(_client(stack, "tenant-a", 120), make_scene(Path(tmp) / "scene"))
        print(
            f"{'size':>7} {'submit s':>9} {'status s':>9} {'page s':>8} {'cancel s':>9}  load  rows/s submit"
        )
        for size in sizes:
            rounds = [one_round(client, scene_id, size, f"r{r}s{size}") for r in range(args.repeats)]
            med = {k: statistics.median(r[k] for r in rounds) for k in rounds[0]}
            load = os.getloadavg()[0]
            out["sizes"][str(size)] = {**med, "rounds": rounds, "load_1min": load}
            print(f"{size:>7} {med['submit_s']:>9.3f} {med['status_s']:>9.4f} {med['page_s']:>8.4f} "
                  f"{med['cancel_s']:>9.3f}  {load:4.1f}  {size / med['submit_s']:,.0f}")  # fmt: skip
        if args.other_tenant:
            figures = other_tenant(
                stack, scene_id, max(s for s in sizes if s <= 5000) if min(sizes) <= 5000 else min(sizes)
            )
            out["other_tenant"] = figures
            print(
                f"tenant B GET /v1/jobs: idle p50 {figures['idle_p50_s'] * 1e3:.1f} ms p99 "
                f"{figures['idle_p99_s'] * 1e3:.1f} ms (n={figures['idle_n']}); during A's submit p50 "
                f"{figures['busy_p50_s'] * 1e3:.1f} ms p99 {figures['busy_p99_s'] * 1e3:.1f} ms "
                f"(n={figures['busy_n']}); p99 ratio {figures['busy_p99_s'] / figures['idle_p99_s']:.2f}"
            )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
