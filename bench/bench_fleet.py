"""Fleet benchmark (issue 20 item 7): fair share, queue wait, single flight and crash safety on a
real stack on this machine.

Each run starts its own stack (a private redis-server, `rclone serve s3`, one uvicorn API and
`--gpu-workers` + `--cpu-workers` prefork Celery workers of concurrency 1, as the service's worker
commands run them), so no run inherits another's perception cache. Scenes are the tiny synthetic
ones of the service tests (`tests/services/support/scene_factory.py`); `--max-frames` keeps jobs short.

Runs:
- **mixed**: tenant A submits a batch of `--a-jobs` (bulk), tenant B one of `--b-jobs` right after,
  tenant C one interactive job every `--c-every-s` seconds until A's and B's batches are finished;
- **single**: the same jobs (scene, tasks) as the mixed run, all from tenant A in one batch (the
  throughput baseline: no fair-share interleaving);
- **kill**: the mixed run again, with one GPU worker SIGKILLed (worker and pool child) once half of
  A's and B's jobs are finished; it is not restarted.

Reported (from the job records the API returns, not from the bench's own clocks): throughput
(succeeded jobs per minute from the first submission to the last finish); queue wait per tenant
(`created_at` -> `started_at`: submission to the first stage starting on a worker, p50 / p99);
Jain's index of A's and B's worker time while both were backlogged; perception runs per scene
(jobs whose perceive stage computed frames, and encoder calls); for the kill run: jobs lost (not
succeeded), jobs that ran a stage more than once (`stage_runs` > 3), and whether each (scene,
tasks) result is byte-identical to the mixed run's (sha256 of every artifact under `result/`).

Usage (from the repository root):
    python -m bench.bench_fleet                       # the issue's sizes: A 1000, B 100, C every 5 s
    nice -n 5 python -m bench.bench_fleet --a-jobs 60 --b-jobs 20 --c-every-s 5 --runs mixed,single,kill
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import threading
import time
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import TYPE_CHECKING, Any

import httpx
import numpy as np

if TYPE_CHECKING:  # the stack's modules are imported where a stack starts; the pure parts need none
    from tests.services.support.private_stack import PrivateStack

Record = dict[str, Any]  # a job record as GET /v1/jobs/{id} returns it
TERMINAL = ("succeeded", "failed", "cancelled")
STAGES = 3  # perceive, fuse, cluster: `stage_runs` of a job that ran each stage once
TENANTS = ("tenant-a", "tenant-b", "tenant-c")
RESULTS_DIR = Path(__file__).resolve().parent / "results"

# ---- pure parts (tested in tests/bench/test_bench_fleet.py) ----------------------------------------


def epoch(value: str | None) -> float | None:
    """Seconds since the epoch of an ISO timestamp of a job record (None stays None)."""
    return None if value is None else datetime.fromisoformat(value).timestamp()


def percentile(values: Sequence[float], q: float) -> float | None:
    """The q-th percentile (linear interpolation, numpy's default); None for no values. With fewer
    than 100 values p99 is close to the maximum: say so when reporting small runs."""
    return float(np.percentile(np.asarray(values, float), q)) if len(values) else None


def jain_index(amounts: Sequence[float]) -> float | None:
    """Jain's fairness index (sum x)^2 / (n sum x^2): 1 when all equal, 1/n when one takes all.
    Amounts are per-weight shares (the tenants' weights are equal here)."""
    x = np.asarray(amounts, float)
    denom = len(x) * float(np.sum(x * x))
    return float(np.sum(x)) ** 2 / denom if denom > 0 else None


def queue_waits(records: Iterable[Record]) -> dict[str, list[float]]:
    """Per tenant, seconds from submission (`created_at`) to the first stage starting
    (`started_at`) of every job that started. Dispatch is a moment earlier; the records carry no
    dispatch time, and the start is what a user waits for."""
    waits: dict[str, list[float]] = defaultdict(list)
    for r in records:
        created, started = epoch(r["created_at"]), epoch(r.get("started_at"))
        if created is not None and started is not None:
            waits[r["tenant"]].append(started - created)
    return dict(waits)


def backlog_window(records: Sequence[Record], tenants: Sequence[str]) -> tuple[float, float] | None:
    """The interval in which every tenant of `tenants` had jobs waiting: from the latest of their
    first submissions to the earliest of their last starts (a tenant's backlog ends when its last
    job starts). None when they never overlapped."""
    ends = []
    for tenant in tenants:
        mine = [r for r in records if r["tenant"] == tenant and r.get("started_at")]
        if not mine:
            return None
        created = min(epoch(r["created_at"]) or 0.0 for r in mine)
        ends.append((created, max(epoch(r["started_at"]) or 0.0 for r in mine)))
    lo, hi = max(e[0] for e in ends), min(e[1] for e in ends)
    return (lo, hi) if hi > lo else None


def worker_seconds(records: Iterable[Record], tenant: str, window: tuple[float, float]) -> float:
    """Worker time of `tenant`'s jobs inside `window`. A job's stage seconds (`timings`, wall time
    of each stage on a worker) are spread evenly over its started..finished interval, since records
    hold no per-stage start times; then the part inside the window is counted."""
    lo, hi = window
    total = 0.0
    for r in records:
        start, end = epoch(r.get("started_at")), epoch(r.get("finished_at"))
        if r["tenant"] != tenant or start is None or end is None or end <= start:
            continue
        busy = sum(float(v) for v in (r.get("timings") or {}).values())
        overlap = max(0.0, min(end, hi) - max(start, lo))
        total += busy * overlap / (end - start)
    return total


def starts_in(records: Iterable[Record], tenant: str, window: tuple[float, float]) -> int:
    """Jobs of `tenant` that started inside `window`: the dispatcher's share, which the stride
    scheduler equalises directly (worker time follows it when jobs cost the same)."""
    lo, hi = window
    return sum(r["tenant"] == tenant and lo <= (epoch(r.get("started_at")) or -1.0) <= hi for r in records)


def throughput_per_min(records: Sequence[Record]) -> float | None:
    """Succeeded jobs per minute from the first submission to the last finish."""
    done = [r for r in records if r["state"] == "succeeded"]
    if not done:
        return None
    t0 = min(epoch(r["created_at"]) or 0.0 for r in records)
    t1 = max(epoch(r["finished_at"]) or 0.0 for r in done)
    return 60.0 * len(done) / (t1 - t0) if t1 > t0 else None


def perception_runs(records: Iterable[Record], labels: dict[str, str]) -> dict[str, dict[str, int]]:
    """Per scene label: jobs, jobs whose perceive stage computed frames (a cache miss; single flight
    should make that 1 per scene), and the encoder calls they made."""
    out: dict[str, dict[str, int]] = {}
    for r in records:
        row = out.setdefault(
            labels.get(r["scene_id"]) or str(r["scene_id"]), {"jobs": 0, "runs": 0, "encoder_calls": 0}
        )
        row["jobs"] += 1
        report = (r.get("stage_reports") or {}).get("perceive") or {}
        row["runs"] += int(report.get("frames_computed", 0) > 0)
        row["encoder_calls"] += int(report.get("encoder_calls", 0))
    return out


def crash_effects(submitted: Sequence[str], records: Sequence[Record]) -> dict[str, Any]:
    """Jobs lost (submitted but not succeeded, or not listed), listed more than once, and those that
    ran a stage more than once (`stage_runs` > 3: a stage execution started again)."""
    seen: dict[str, int] = defaultdict(int)
    for r in records:
        seen[r["id"]] += 1
    ok = {r["id"] for r in records if r["state"] == "succeeded"}
    rerun = sorted((r["id"], r["stage_runs"]) for r in records if r["stage_runs"] > STAGES)
    return {
        "submitted": len(submitted),
        "lost": {
            r["id"]: f"{r['state']} (stage_runs {r['stage_runs']})" for r in records if r["id"] not in ok
        }
        | {j: "not listed" for j in set(submitted) - {r["id"] for r in records}},
        "listed_twice": sorted(j for j, n in seen.items() if n > 1),
        "ran_a_stage_twice": [{"id": j, "stage_runs": n} for j, n in rerun],
    }


def compare_digests(base: dict[str, dict[str, str]], other: dict[str, dict[str, str]]) -> dict[str, Any]:
    """Result digests (artifact path -> sha256) per (scene, tasks) key of two runs: how many keys
    both have, which differ, and which artifact paths differed (to tell a real difference from one
    file that carries run-dependent data)."""
    common = sorted(set(base) & set(other))
    differ = [k for k in common if base[k] != other[k]]
    paths = sorted(
        {p for k in differ for p in set(base[k]) | set(other[k]) if base[k].get(p) != other[k].get(p)}
    )
    return {"compared": len(common), "identical": len(common) - len(differ), "differ": differ, "paths": paths}


def artifact_digest(path: str, data: bytes) -> str:
    """sha256 of an artifact's bytes, everything byte for byte except two fields of `summary.json`
    that differ between any two runs by design: `timings_s` (wall-clock seconds of the cluster
    steps) and `scene.store_prefix` (where the scene was uploaded: it holds the scene id). The
    summary also lists every other file's checksum, so those are still compared."""
    if path.endswith("summary.json"):
        summary = json.loads(data)
        summary.pop("timings_s", None)
        if isinstance(summary.get("scene"), dict):
            summary["scene"].pop("store_prefix", None)
        data = json.dumps(summary, sort_keys=True).encode()
    return hashlib.sha256(data).hexdigest()


# ---- the stack ------------------------------------------------------------------------------------


@contextmanager
def fleet_stack(workdir: Path, keys: dict[str, str], gpu: int, cpu: int) -> Iterator[PrivateStack]:
    """A fresh stack from the service tests' building blocks: their private Redis + API + worker
    pool (`PrivateStack`) on an rclone S3 server of its own. Crash recovery is the service tests'
    fast one (stage locks expire 6 s after a crash, scans every 2 s), so a killed worker's job is
    picked up in seconds rather than the production minute; every other setting is the default."""
    from tests.integration.fixtures.s3_server import S3Server
    from tests.services.conftest import SERVICE_ENV
    from tests.services.support.private_stack import PrivateStack

    fast_recovery = {k: v for k, v in SERVICE_ENV.items() if "LOCK_TTL" in k or "RECOVERY" in k}
    s3 = S3Server(workdir / "s3").start()
    stack = PrivateStack(workdir, s3.env(), keys, fast_recovery)
    try:
        stack.start()
        assert stack.pool is not None and stack.api is not None
        for queue, count in (("gpu", gpu), ("cpu", cpu)):
            for i in range(count):
                stack.pool.start(queue, name=f"{queue}-{i + 1}", pool="prefork", timeout_s=180)
        yield stack
    finally:
        stack.stop()
        s3.stop()


# ---- one run --------------------------------------------------------------------------------------


@dataclass
class Run:
    """What one run leaves: every job record, scene labels, result digests, load samples."""

    name: str
    records: list[Record] = field(default_factory=list)
    submitted: list[str] = field(default_factory=list)
    labels: dict[str, str] = field(default_factory=dict)  # scene id -> label
    digests: dict[str, dict[str, str]] = field(default_factory=dict)  # "label|tasks" -> path -> sha
    load: list[float] = field(default_factory=list)  # 1-min load average samples
    killed_at: float | None = None
    stalled: bool = False  # the wait ended because nothing finished for --stall-s
    wall_s: float = 0.0


def _key(label: str, tasks: Sequence[str]) -> str:
    return f"{label}|{json.dumps(list(tasks))}"


def _submit_batch(client: httpx.Client, items: list[tuple[str, list[str]]], params: dict[str, Any]) -> str:
    resp = client.post("/v1/batches", json={"items": [{"scene_id": s, "tasks": t} for s, t in items],
                                            "parameters": params})  # fmt: skip
    resp.raise_for_status()
    return str(resp.json()["id"])


def _batch_records(client: httpx.Client, batch_id: str) -> list[Record]:
    out: list[Record] = []
    cursor: str | None = None
    while True:
        page = client.get(
            f"/v1/batches/{batch_id}/jobs", params={"limit": 500, **({"cursor": cursor} if cursor else {})}
        )
        body = page.raise_for_status().json()
        out += body["items"]
        cursor = body["next_cursor"]
        if not cursor:
            return out


def _result_digests(client: httpx.Client, job_id: str) -> dict[str, str]:
    """Artifact path -> digest of every result artifact, fetched through the API's links."""
    result = client.get(f"/v1/jobs/{job_id}/result").raise_for_status().json()
    out = {}
    for art in result["artifacts"]:
        # presigned S3 links are absolute (fetched without the API key); others are API paths
        url = str(art["url"])
        resp = httpx.get(url, timeout=60) if url.startswith("http") else client.get(url)
        out[art["path"]] = artifact_digest(art["path"], resp.raise_for_status().content)
    return out


def run_scenario(
    name: str, args: argparse.Namespace, scenes: dict[str, Path], plan: dict[str, list[tuple[str, list[str]]]],
    *, c_jobs: bool, kill: bool, workdir: Path,
) -> Run:  # fmt: skip
    """Start a stack, upload the scenes, submit `plan` (tenant -> [(scene label, tasks)], one batch
    each), add C's interactive jobs while the batches run, optionally kill a GPU worker half-way, wait
    for every job (or `--timeout-s`), then read the records and result digests."""
    from tests.services.support.private_stack import upload

    keys = {t: f"key-{t}-bench-{os.getpid()}" for t in TENANTS}
    run = Run(name)
    params = {"max_frames": args.max_frames}
    with fleet_stack(workdir, keys, args.gpu_workers, args.cpu_workers) as stack:
        api, pool = stack.api, stack.pool
        assert api is not None and pool is not None
        clients = {t: api.client(t) for t in TENANTS}
        ids: dict[str, dict[str, str]] = defaultdict(dict)  # tenant -> label -> scene id
        uploads = {t: sorted({lab for lab, _ in items}) for t, items in plan.items()}
        for tenant, labels in {**uploads, **({"tenant-c": ["c0"]} if c_jobs else {})}.items():
            for label in labels:
                ids[tenant][label] = upload(clients[tenant], scenes[label])
                run.labels[ids[tenant][label]] = label
        print(f"[{name}] stack up, scenes uploaded; submitting", flush=True)
        t0 = time.monotonic()
        batches = {t: _submit_batch(clients[t], [(ids[t][lab], tasks) for lab, tasks in items], params)
                   for t, items in plan.items()}  # fmt: skip
        c_ids: list[str] = []
        done = threading.Event()

        def submit_c() -> None:
            k = 0
            while not done.is_set():
                resp = clients["tenant-c"].post("/v1/jobs", json={"scene_id": ids["tenant-c"]["c0"],
                                                "tasks": [f"red blob {k}"], "parameters": params})  # fmt: skip
                c_ids.append(resp.raise_for_status().json()["id"])
                k += 1
                done.wait(args.c_every_s)

        c_thread = threading.Thread(target=submit_c, daemon=True)
        if c_jobs:
            c_thread.start()
        total = sum(len(v) for v in plan.values())
        deadline = t0 + args.timeout_s
        progress = (-1, time.monotonic())  # (finished, when it last changed)
        while time.monotonic() < deadline:
            counts = [
                clients[t].get(f"/v1/batches/{b}", params={"jobs": "false"}).json()
                for t, b in batches.items()
            ]
            finished = sum(sum(n for s, n in c["counts"].items() if s in TERMINAL) for c in counts)
            run.load.append(os.getloadavg()[0])
            if kill and run.killed_at is None and finished >= total / 2:
                victim = next(w for w in pool.workers if w.queue == "gpu")
                victim.kill()
                run.killed_at = time.time()
                print(f"[{name}] SIGKILLed {victim.node} at {finished}/{total} finished", flush=True)
            if all(c["finished"] for c in counts):
                break
            if finished != progress[0]:
                progress = (finished, time.monotonic())
            elif time.monotonic() - progress[1] > args.stall_s:
                # crash recovery (stage lock TTL + scans) acts within seconds; a job not rescued in
                # stall_s waits for the broker's visibility timeout (hours): record it as lost
                print(f"[{name}] no batch job finished for {args.stall_s:.0f} s: stopping", flush=True)
                run.stalled = True
                break
            time.sleep(2)
        done.set()
        if c_jobs:
            c_thread.join()
        deadline = min(deadline, time.monotonic() + args.stall_s)
        for job_id in c_ids:  # C's last jobs were submitted at most one interval before
            while (
                time.monotonic() < deadline
                and clients["tenant-c"].get(f"/v1/jobs/{job_id}").json()["state"] not in TERMINAL
            ):
                time.sleep(1)
        run.wall_s = time.monotonic() - t0
        for tenant, batch_id in batches.items():
            run.records += _batch_records(clients[tenant], batch_id)
        run.records += [clients["tenant-c"].get(f"/v1/jobs/{j}").json() for j in c_ids]
        run.submitted = [r["id"] for r in run.records]
        for r in run.records:
            if r["state"] == "succeeded":
                run.digests[_key(run.labels[r["scene_id"]], r["tasks"])] = _result_digests(
                    clients[r["tenant"]], r["id"]
                )
        for client in clients.values():
            client.close()
    return run


def summarise(run: Run, base: Run | None) -> dict[str, Any]:
    """The reported numbers of one run (see the module docstring)."""
    waits = queue_waits(run.records)
    window = backlog_window(run.records, ("tenant-a", "tenant-b"))
    shares = [worker_seconds(run.records, t, window) for t in ("tenant-a", "tenant-b")] if window else []
    starts = [starts_in(run.records, t, window) for t in ("tenant-a", "tenant-b")] if window else []
    out: dict[str, Any] = {
        "jobs": len(run.records),
        "succeeded": sum(r["state"] == "succeeded" for r in run.records),
        "wall_s": round(run.wall_s, 1),
        "jobs_per_min": throughput_per_min(run.records),
        "wait_s": {
            t: {"n": len(w), "p50": percentile(w, 50), "p99": percentile(w, 99)}
            for t, w in sorted(waits.items())
        },
        "backlog_window_s": None if window is None else round(window[1] - window[0], 1),
        "worker_s_a_b": [round(s, 1) for s in shares],
        "jain_a_b": jain_index(shares) if shares else None,
        "starts_a_b": starts,
        "jain_starts_a_b": jain_index(starts) if starts else None,
        "perception": perception_runs(run.records, run.labels),
        "crash": crash_effects(run.submitted, run.records),
        "stalled": run.stalled,
        "load_1min": {"mean": round(float(np.mean(run.load)), 2), "max": round(max(run.load), 2)}
        if run.load
        else None,
    }
    if base is not None:
        out["results_vs_mixed"] = compare_digests(base.digests, run.digests)
    return out


def _fmt(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def print_table(summaries: dict[str, dict[str, Any]]) -> None:
    rows = ["run", "jobs (ok)", "wall s", "jobs/min", "wait p50/p99 A", "wait p50/p99 B", "wait p50/p99 C",
            "Jain A:B time/starts", "perception runs/scene", "lost", "stage_runs>3", "identical to mixed", "load 1m mean/max"]  # fmt: skip
    cells = []
    for name, s in summaries.items():
        w = s["wait_s"]

        def wait(t: str, w: dict[str, Any] = w) -> str:
            return f"{_fmt(w[t]['p50'])}/{_fmt(w[t]['p99'])} (n={w[t]['n']})" if t in w else "-"

        same = s.get("results_vs_mixed")
        cells.append([name, f"{s['jobs']} ({s['succeeded']})", _fmt(s["wall_s"], 0), _fmt(s["jobs_per_min"], 2),
                      wait("tenant-a"), wait("tenant-b"), wait("tenant-c"), f"{_fmt(s['jain_a_b'], 3)} / {_fmt(s['jain_starts_a_b'], 3)}",
                      " ".join(f"{k}:{v['runs']}/{v['jobs']}" for k, v in sorted(s["perception"].items())),
                      str(len(s["crash"]["lost"])), str(len(s["crash"]["ran_a_stage_twice"])),
                      "-" if same is None else f"{same['identical']}/{same['compared']}",
                      f"{s['load_1min']['mean']}/{s['load_1min']['max']}" if s["load_1min"] else "-"])  # fmt: skip
    for i, head in enumerate(rows):
        print(f"| {head:<22} | " + " | ".join(c[i] for c in cells) + " |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--a-jobs", type=int, default=1000, help="tenant A's batch size")
    p.add_argument("--b-jobs", type=int, default=100, help="tenant B's batch size")
    p.add_argument("--c-every-s", type=float, default=5.0, help="seconds between tenant C's interactive jobs")
    p.add_argument("--a-scenes", type=int, default=2, help="scenes A's jobs cycle through")
    p.add_argument("--max-frames", type=int, default=4)
    p.add_argument("--frames", type=int, default=4, help="frames of each synthetic scene")
    p.add_argument("--gpu-workers", type=int, default=2)
    p.add_argument("--cpu-workers", type=int, default=2)
    p.add_argument("--runs", default="mixed,single,kill", help="comma-separated: mixed, single, kill")
    p.add_argument(
        "--single-jobs",
        type=int,
        default=None,
        help="jobs of the single-tenant run (default: as many as mixed ran)",
    )
    p.add_argument(
        "--stall-s", type=float, default=180, help="stop waiting when no batch job finished for this long"
    )
    p.add_argument(
        "--timeout-s", type=float, default=24 * 3600, help="per run; unfinished jobs then count as lost"
    )
    p.add_argument(
        "--out", type=Path, default=None, help="JSON report (default bench/results/fleet-<time>.json)"
    )
    args = p.parse_args()
    from tests.services.support.scene_factory import make_scene

    runs = args.runs.split(",")
    started = datetime.now().astimezone()
    report: dict[str, Any] = {"args": {k: str(v) for k, v in vars(args).items()}, "cpus": os.cpu_count(),
                              "load_before": os.getloadavg(), "started": started.isoformat(), "runs": {}}  # fmt: skip
    a_items = [(f"a{i % args.a_scenes}", [f"red blob {i}"]) for i in range(args.a_jobs)]
    b_items = [("b0", [f"green blob {i}"]) for i in range(args.b_jobs)]
    results: dict[str, Run] = {}
    with TemporaryDirectory(prefix="bfields-fleet-") as tmp:
        labels = [f"a{i}" for i in range(args.a_scenes)] + ["b0", "c0"]
        scenes = {
            lab: make_scene(Path(tmp) / "scenes" / lab, frames=args.frames, seed=i)
            for i, lab in enumerate(labels)
        }
        for name in runs:
            if name == "single":  # the mixed run's jobs (C's as many as it submitted), all from A
                mixed = results.get("mixed")
                c_items = [(mixed.labels[r["scene_id"]], r["tasks"]) for r in mixed.records
                           if r["tenant"] == "tenant-c"] if mixed else []  # fmt: skip
                plan = {"tenant-a": (a_items + b_items + c_items)[: args.single_jobs]}
            else:
                plan = {"tenant-a": a_items, "tenant-b": b_items}
            run = run_scenario(name, args, scenes, plan, c_jobs=name != "single", kill=name == "kill",
                               workdir=Path(tmp) / name)  # fmt: skip
            results[name] = run
            report["runs"][name] = summarise(run, results.get("mixed") if name != "mixed" else None)
            print(json.dumps({name: report["runs"][name]}, default=str)[:2000], flush=True)
    report["load_after"] = os.getloadavg()
    out = args.out or RESULTS_DIR / f"fleet-{started:%Y%m%d-%H%M}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1, default=str))
    print_table(report["runs"])
    print(f"written {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
