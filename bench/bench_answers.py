"""Fleet answers at fleet size on the real stack (issue 42, item 7).

Targets: for a 50,000-job batch of 8 tasks x 5 objects (2 M answer rows), a filtered page of the
batch's answers < 50 ms, the fleet search < 100 ms, the whole batch streamed as CSV < 60 s with
the API's memory growing < 100 MiB, writing one job's answers adds < 20 ms to its finish, and
another tenant's `GET /v1/jobs` p99 during the export within 2x of idle.

What is real and what is not. The stack is real (`bench_batch_ops.batch_stack`: a private Redis,
`rclone serve s3`, a PostgreSQL database of its own, one uvicorn API with its bulk lane and the
control process; no workers). The batch is real: `--jobs` jobs submitted through
`POST /v1/batches`, over `--scenes` scenes of tenant A (the sample scene uploaded once, the
others registered in the records as copies of its row, since uploading thousands of scenes
measures uploads, not answers). **The jobs' answers are not made by running the pipeline
50,000 times** (hours on this machine): the bench runs `bfields run samples/tabletop` once (or
reads `--result DIR`, such a run's output), makes `VARIANTS` summaries of it with 5 objects per
task and their probabilities varied, turns each into rows with the domain's own builder
(`jobs.answers.answer_rows`), and then, `CHUNK` jobs per transaction, marks the jobs succeeded
with one `UPDATE` (the batch counters follow through the records' triggers) and writes each
job's rows with `records.answers.replace_job` (each job's probabilities scaled by a factor of its
own). Usage-ledger and callback rows of those jobs are not written (nothing here reads them).
The filled tables are then vacuumed and analysed (`settle`), as autovacuum leaves a table in
steady state.

What is measured, all through real HTTP on the API unless said:

- `write_ms`: what one job's answers add to its finish (after the fill: into the full table),
  measured on the real finish path in the bench process: (read the summary from S3 and build the rows, `jobs.answers.rows_for_finish`,
  + `JobStore.save(succeeded, answers=rows)`) minus `JobStore.save(succeeded)` without answers,
  medians over `--finishes` jobs each, the two kinds interleaved;
- `page_s`: `GET /v1/batches/{id}/answers?task=..&min_probability=..&limit=100`, the first page
  and a page from the middle of the batch (a cursor there), median and p95 of `--reads` each;
- `search_s`: `GET /v1/answers?task=..` (the fleet's best answer per scene, ranked), median/p95;
- `export_s`, `export_rss_mib`: the whole batch as CSV (`format=csv`, read as a stream), and the
  API process's resident memory (VmRSS from /proc, sampled every 20 ms) at its highest during
  the stream less before it (VmHWM, the kernel's high-water mark, is printed too);
- another tenant's `GET /v1/jobs?limit=20` (bench/latency_probe.py, a process of its own) p50 / p99
  idle, then during the export.

The machine's load average is printed and written. Usage (repository root):

    python -m bench.bench_answers --json bench/results/answers.json
    python -m bench.bench_answers --jobs 5000 --scenes 500
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx

from bench.bench_batch_ops import _client, _ok, _pct, _start_probe, batch_stack

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "samples" / "tabletop"
OBJECTS = 5  # ranked objects per task, as the 8 tasks x 5 objects
VARIANTS = 64  # distinct summaries the rows are made from
CHUNK = 500  # jobs per transaction of the bulk fill
TARGETS = {"page_s": 0.050, "search_s": 0.100, "export_s": 60.0, "export_rss_mib": 100.0, "write_ms": 20.0}


def sample_tasks() -> list[str]:
    import yaml

    return [str(t["task"]) for t in yaml.safe_load((SAMPLE / "tasks.yaml").read_text())["tasks"]]


def real_summary(result: Path | None, workdir: Path) -> dict[str, Any]:
    """The summary.json of a real `bfields run samples/tabletop` (run here unless `result` is one)."""
    if result is None:
        result = workdir / "cli-run"
        t0 = time.monotonic()
        cmd = [sys.executable, "-m", "bayesian_fields_core.cli", "run", str(SAMPLE), "--out", str(result)]
        subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        print(f"bfields run samples/tabletop: {time.monotonic() - t0:.0f} s")
    found = sorted(result.rglob("summary.json"))
    if not found:
        raise SystemExit(f"{result}: no summary.json (give a `bfields run` output folder)")
    return json.loads(found[0].read_text())


def variant_summaries(summary: dict[str, Any], n: int, seed: int = 42) -> list[dict[str, Any]]:
    """`n` copies of the real summary in which every task has `OBJECTS` ranked objects (its own
    first, then the scene's other selected objects) with probabilities drawn per variant."""
    rng = random.Random(seed)
    pool: dict[int, dict[str, Any]] = {}
    for entry in summary["selections"]:
        for obj in entry.get("objects") or []:
            pool.setdefault(int(obj["object_id"]), obj)
    if len(pool) < OBJECTS:
        raise SystemExit(f"the result selected {len(pool)} objects in all; {OBJECTS} per task are needed")
    out = []
    for _ in range(n):
        varied = copy.deepcopy(summary)
        for entry in varied["selections"]:
            own = list(entry.get("objects") or [])
            ids = {int(o["object_id"]) for o in own}
            others = [o for i, o in pool.items() if i not in ids]
            rng.shuffle(others)
            chosen = [copy.deepcopy(o) for o in (own + others)[:OBJECTS]]
            p = rng.uniform(0.05, 0.99)
            for obj in chosen:
                obj["probability"] = p
                p *= rng.uniform(0.5, 0.95)
            entry["objects"] = chosen
            entry.pop("not_found", None)
        out.append(varied)
    return out


def variant_rows(variants: list[dict[str, Any]], workdir: Path, tenant: str) -> list[list[dict[str, Any]]]:
    """Each variant's rows by the domain's builder (`answer_rows`), read back from a store."""
    from bayesian_fields_core.job.store import LocalStore
    from bayesian_fields_service.common.jobs import JobRecord
    from bayesian_fields_service.jobs.answers import answer_rows

    store = LocalStore(workdir / "variants")
    out = []
    for i, summary in enumerate(variants):
        job = JobRecord.model_construct(id=f"j_variant{i:04d}", tenant=tenant, scene_id="s_variant")
        store.put_bytes(f"{job.job_prefix}result/summary.json", json.dumps(summary).encode())
        out.append(answer_rows(store, job, datetime.now(UTC)))
    return out


def _job_ids(client: httpx.Client, batch_id: str) -> list[tuple[str, str]]:
    """(job id, scene id) of every job of the batch, in its order."""
    out: list[tuple[str, str]] = []
    cursor = None
    while True:
        params: dict[str, Any] = {"limit": 500, **({"cursor": cursor} if cursor else {})}
        page = _ok(client.get(f"/v1/batches/{batch_id}/jobs", params=params)).json()
        out += [(j["id"], j["scene_id"]) for j in page["items"]]
        if not (cursor := page.get("next_cursor")):
            return out


def register_scenes(database: Any, tenant: str, template_id: str, n: int) -> list[str]:
    """`n - 1` scene rows copied from the uploaded one (new ids and names; the same files)."""
    from bayesian_fields_service.common.jobs import new_id
    from bayesian_fields_service.records import scenes as scene_records

    with database.begin() as conn:
        row = dict(scene_records.load(conn, tenant, template_id))
        ids = [template_id]
        for i in range(1, n):
            ids.append(new_id("s_"))
            scene_records.insert_row(conn, {**row, "id": ids[-1], "name": f"room-{i:05d}"})
    return ids


def fill(database: Any, jobs: list[tuple[str, str]], rows: list[list[dict[str, Any]]], tenant: str) -> float:
    """Mark `jobs` succeeded and write their answers (module docstring); returns seconds taken."""
    from sqlalchemy import update

    from bayesian_fields_service.records import answers as answer_records
    from bayesian_fields_service.records.tables import jobs as job_table

    rng = random.Random(7)
    t0 = time.monotonic()
    base = datetime.now(UTC) - timedelta(hours=1)
    for start in range(0, len(jobs), CHUNK):
        chunk = jobs[start : start + CHUNK]
        finished = base + timedelta(milliseconds=start)
        with database.begin() as conn:
            conn.execute(
                update(job_table)
                .where(job_table.c.id.in_([j for j, _ in chunk]), job_table.c.tenant == tenant)
                .values(state="succeeded", progress=100.0, stages_done=["perceive", "fuse", "cluster"],
                        started_at=finished, finished_at=finished, dispatched_at=finished)
            )  # fmt: skip
            for n, (job_id, scene_id) in enumerate(chunk):
                scale = rng.uniform(0.9, 1.0)
                mine = [
                    {**r, "job_id": job_id, "scene_id": scene_id, "finished_at": finished,
                     "probability": r["probability"] * scale if r["probability"] is not None else None}
                    for r in rows[(start + n) % len(rows)]
                ]  # fmt: skip
                answer_records.replace_job(conn, job_id, mine)
        done = start + len(chunk)
        if done % 5000 < CHUNK or done == len(jobs):
            rate = done / (time.monotonic() - t0)
            print(f"  {done:,} jobs filled ({rate:,.0f} jobs/s)", flush=True)
    return time.monotonic() - t0


def settle(database: Any) -> int:
    """VACUUM (ANALYZE) the tables the fill wrote, as autovacuum does to a table in steady state
    (it sets the visibility map that index-only scans need, and the reads are then not timed
    against a vacuum of the fill's 2 M fresh rows); the answer rows counted."""
    from sqlalchemy import text

    t0 = time.monotonic()
    with database.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        conn.execute(text("VACUUM (ANALYZE) answers, batch_jobs, jobs"))
        n_rows = int(conn.execute(text("SELECT count(*) FROM answers")).scalar_one())
    print(f"VACUUM (ANALYZE) after the fill: {time.monotonic() - t0:.0f} s")
    return n_rows


def measure_write(stack: Any, s3: Any, jobs: list[tuple[str, str]], summaries: list[dict[str, Any]],
                  tenant: str) -> dict[str, float]:  # fmt: skip
    """`write_ms` (module docstring): half of `jobs` finished with answers, half without."""
    from bayesian_fields_service.common.jobs import JobState, JobStore, utcnow
    from bayesian_fields_service.jobs.answers import rows_for_finish
    from bayesian_fields_service.records.database import engine

    store = JobStore(s3, stack.redis, engine(stack.env["BFIELDS_DATABASE_URL"]))
    with_rows: list[float] = []
    build: list[float] = []
    without: list[float] = []
    for n, (job_id, _) in enumerate(jobs):
        record = store.load(tenant, job_id)
        assert record is not None
        done = record.model_copy(
            update={"state": JobState.succeeded, "finished_at": utcnow(), "progress": 100.0}
        )
        if n % 2 == 0:
            store.tenant(tenant).put_bytes(f"{record.job_prefix}result/summary.json",
                                           json.dumps(summaries[n % len(summaries)]).encode())  # fmt: skip
            t0 = time.perf_counter()
            rows = rows_for_finish(store.tenant(tenant), record, done.finished_at)
            t1 = time.perf_counter()
            store.save(done, answers=rows)
            t2 = time.perf_counter()
            assert len(rows) == 8 * OBJECTS, len(rows)
            build.append(t1 - t0)
            with_rows.append(t2 - t1)
        else:
            t0 = time.perf_counter()
            store.save(done)
            without.append(time.perf_counter() - t0)
    return {
        "write_ms": (statistics.median([b + w for b, w in zip(build, with_rows, strict=True)])
                     - statistics.median(without)) * 1e3,
        "finish_without_answers_ms": statistics.median(without) * 1e3,
        "save_with_answers_ms": statistics.median(with_rows) * 1e3,
        "rows_for_finish_ms": statistics.median(build) * 1e3,
        "finishes": len(jobs),
    }  # fmt: skip


def _timings(fn: Callable[[], httpx.Response], n: int) -> tuple[list[float], httpx.Response]:
    took, resp = [], None
    for _ in range(n):
        t0 = time.perf_counter()
        resp = _ok(fn())
        took.append(time.perf_counter() - t0)
    assert resp is not None
    return took, resp


def _stats(prefix: str, took: list[float]) -> dict[str, float]:
    return {f"{prefix}_s": statistics.median(took), f"{prefix}_p95_s": _pct(took, 0.95)}


def measure_reads(client: httpx.Client, batch_id: str, task: str, n_jobs: int, reads: int,
                  min_probability: float) -> dict[str, Any]:  # fmt: skip
    path = f"/v1/batches/{batch_id}/answers"
    params = {"task": task, "min_probability": min_probability, "limit": 100}
    first, resp = _timings(lambda: client.get(path, params=params), reads)
    page = resp.json()
    assert page["task"] == task and len(page["items"]) == 100, page.get("task")
    assert all(r["probability"] >= min_probability and r["task"] == task for r in page["items"])
    middle_params = {**params, "cursor": f"{n_jobs // 2}.0.0"}
    middle, resp = _timings(lambda: client.get(path, params=middle_params), reads)
    assert len(resp.json()["items"]) == 100
    search, resp = _timings(lambda: client.get("/v1/answers", params={"task": task}), reads)
    body = resp.json()
    assert body["asked"] > 0 and body["items"], body
    out = {**_stats("page_first", first), **_stats("page_middle", middle), **_stats("search", search),
           "search_asked": body["asked"], "search_found": body["found"]}  # fmt: skip
    out["page_s"] = max(out["page_first_s"], out["page_middle_s"])
    return out


def explain(database: Any, call: Callable[[], Any]) -> dict[str, Any]:
    """`call` (a records function) timed in this process, and EXPLAIN ANALYZE of each statement
    it issued (caught as the driver sends it): where a slow route spends its time."""
    from sqlalchemy import event

    sent: list[tuple[str, Any]] = []

    def catch(conn: Any, cursor: Any, statement: str, params: Any, context: Any, many: bool) -> None:
        sent.append((statement, params))

    event.listen(database, "before_cursor_execute", catch)
    try:
        took = []
        for _ in range(15):  # past psycopg's prepare threshold (5) and PostgreSQL's custom plans (5)
            sent.clear()
            t0 = time.perf_counter()
            call()
            took.append(time.perf_counter() - t0)
    finally:
        event.remove(database, "before_cursor_execute", catch)
    plans = []
    with database.connect() as conn:
        raw = conn.connection.driver_connection
        for statement, params in sent:
            with raw.cursor() as cursor:
                cursor.execute("EXPLAIN (ANALYZE, BUFFERS) " + statement, params)
                plans.append("\n".join(r[0] for r in cursor.fetchall()))
        conn.rollback()
    return {"in_process_s": statistics.median(took), "each_s": took, "plans": plans}


def _execution_ms(plan: str) -> str:
    return next((line.split(":")[1].strip() for line in plan.splitlines() if "Execution Time" in line), "?")


def _rss_kib(pid: int) -> tuple[int, int]:
    """(VmRSS, VmHWM) of `pid` in KiB, from /proc."""
    fields = dict(
        line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line
    )
    return int(fields["VmRSS"].split()[0]), int(fields["VmHWM"].split()[0])


def measure_export(stack: Any, client: httpx.Client, batch_id: str, idle_s: float) -> dict[str, Any]:
    """The CSV stream's time, the API's memory during it, and tenant B's latency idle and during."""
    pid = stack.api.process.popen.pid
    probe = _start_probe(stack)
    peak = [0]
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            peak[0] = max(peak[0], _rss_kib(pid)[0])
            time.sleep(0.02)

    try:
        idle_from = time.monotonic()
        time.sleep(idle_s)
        rss0, hwm0 = _rss_kib(pid)
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        busy_from = time.monotonic()
        size = lines = 0
        with client.stream("GET", f"/v1/batches/{batch_id}/answers", params={"format": "csv"}) as resp:
            _ok(resp)
            for chunk in resp.iter_bytes():
                size += len(chunk)
                lines += chunk.count(b"\n")
        busy_to = time.monotonic()
        stop.set()
        sampler.join()
        rss1, hwm1 = _rss_kib(pid)
    finally:
        out, _ = probe.communicate("", timeout=300)
    samples = [(float(a), float(b)) for a, b in (line.split() for line in out.splitlines())]
    idle = [t for s, t in samples if idle_from <= s and s + t <= busy_from]
    busy = [t for s, t in samples if busy_from <= s < busy_to]
    return {
        "export_s": busy_to - busy_from, "export_bytes": size, "export_rows": lines - 1,
        "export_rss_mib": (max(peak[0], rss1) - rss0) / 1024, "api_rss_before_mib": rss0 / 1024,
        "api_hwm_before_mib": hwm0 / 1024, "api_hwm_after_mib": hwm1 / 1024,
        "idle_p50_s": _pct(idle, 0.5), "idle_p99_s": _pct(idle, 0.99), "idle_n": len(idle),
        "busy_p50_s": _pct(busy, 0.5), "busy_p99_s": _pct(busy, 0.99), "busy_n": len(busy),
    }  # fmt: skip


def explain_reads(database: Any, tenant: str, batch_id: str, task: str, n_jobs: int,
                  min_probability: float) -> dict[str, Any]:  # fmt: skip
    """The records functions behind the page and the search, timed here and explained."""
    from bayesian_fields_service.records import answers as records

    wanted = records.AnswerFilter(task=task, min_probability=min_probability)
    out = {
        "matching_tasks": explain(database, lambda: records.matching_tasks(database, tenant, task, batch_id=batch_id)),
        "page_first": explain(database, lambda: records.batch_page(database, tenant, batch_id, wanted, after=None, limit=101)),
        "page_middle": explain(database, lambda: records.batch_page(database, tenant, batch_id, wanted,
                                                                    after=(n_jobs // 2, 0, 0), limit=101)),
        "fleet": explain(database, lambda: records.fleet(database, tenant, task, limit=101)),
    }  # fmt: skip
    for name, got in out.items():
        ms = ", ".join(_execution_ms(p) for p in got["plans"])
        each = " ".join(f"{t * 1e3:.0f}" for t in got["each_s"])
        print(
            f"  {name}: {got['in_process_s'] * 1e3:.1f} ms in process ({each}); EXPLAIN ANALYZE execution {ms}"
        )
    return out


def report(figures: dict[str, Any]) -> None:
    def verdict(name: str, value: float) -> str:
        return "ok" if value < TARGETS[name] else "MISSED"

    ms = 1e3
    print(f"\nfleet answers, {figures['jobs']:,} jobs x 8 tasks x {OBJECTS} objects = {figures['rows']:,} rows "
          f"over {figures['scenes']:,} scenes (rows written directly, not by running the pipeline per job)")  # fmt: skip
    print(f"{'what':<46} {'median':>10} {'p95':>10} {'target':>9}")
    rows = [
        ("filtered page, first (task + min_probability)", figures["page_first_s"] * ms,
         figures["page_first_p95_s"] * ms, "< 50 ms", verdict("page_s", figures["page_first_s"])),
        ("filtered page, middle of the batch", figures["page_middle_s"] * ms,
         figures["page_middle_p95_s"] * ms, "< 50 ms", verdict("page_s", figures["page_middle_s"])),
        ("fleet search GET /v1/answers?task=", figures["search_s"] * ms, figures["search_p95_s"] * ms,
         "< 100 ms", verdict("search_s", figures["search_s"])),
    ]  # fmt: skip
    for what, med, p95, target, ok in rows:
        print(f"{what:<46} {med:>8.1f}ms {p95:>8.1f}ms {target:>9} {ok}")
    print(f"{'CSV export of the batch':<46} {figures['export_s']:>9.1f}s {'':>10} {'< 60 s':>9} "
          f"{verdict('export_s', figures['export_s'])}  ({figures['export_rows']:,} rows, "
          f"{figures['export_bytes'] / 2**20:,.0f} MiB)")  # fmt: skip
    print(f"{'API RSS growth during the export':<46} {figures['export_rss_mib']:>7.1f}MiB {'':>10} "
          f"{'< 100 MiB':>9} {verdict('export_rss_mib', figures['export_rss_mib'])}  (RSS before "
          f"{figures['api_rss_before_mib']:.0f} MiB, VmHWM {figures['api_hwm_before_mib']:.0f} -> "
          f"{figures['api_hwm_after_mib']:.0f} MiB)")  # fmt: skip
    print(f"{'answers added to one job finish':<46} {figures['write_ms']:>8.1f}ms {'':>10} {'< 20 ms':>9} "
          f"{verdict('write_ms', figures['write_ms'])}  (rows_for_finish {figures['rows_for_finish_ms']:.1f} ms "
          f"+ save with rows {figures['save_with_answers_ms']:.1f} ms vs save without "
          f"{figures['finish_without_answers_ms']:.1f} ms, n={figures['finishes']})")  # fmt: skip
    ratio = figures["busy_p99_s"] / figures["idle_p99_s"]
    print(f"tenant B GET /v1/jobs: idle p50 {figures['idle_p50_s'] * ms:.1f} ms p99 {figures['idle_p99_s'] * ms:.1f} ms "
          f"(n={figures['idle_n']}); during the export p50 {figures['busy_p50_s'] * ms:.1f} ms p99 "
          f"{figures['busy_p99_s'] * ms:.1f} ms (n={figures['busy_n']}); p99 ratio {ratio:.2f}x "
          f"(goal: within 2x) {'ok' if ratio <= 2 else 'MISSED'}")  # fmt: skip
    print(f"submit {figures['submit_s']:.1f} s, fill {figures['fill_s']:.0f} s; load average "
          f"{figures['load_before']} before, {figures['load_after']} after ({os.cpu_count()} CPUs)")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=50_000, help="jobs in the batch")
    parser.add_argument("--scenes", type=int, default=5_000, help="tenant A's scenes the batch covers")
    parser.add_argument("--result", type=Path, help="a `bfields run samples/tabletop` output (else run here)")
    parser.add_argument("--reads", type=int, default=30, help="timed reads of each page and the search")
    parser.add_argument(
        "--finishes", type=int, default=40, help="jobs finished for write_ms (half with answers)"
    )
    parser.add_argument("--min-probability", type=float, default=0.5)
    parser.add_argument(
        "--idle-s", type=float, default=10.0, help="tenant B's idle sampling before the export"
    )
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()

    from bayesian_fields_service.records.database import engine
    from tests.services.support.private_stack import upload

    tenant = "tenant-a"
    tasks = sample_tasks()
    load_before = [round(x, 2) for x in os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="bench-answers-") as tmp:
        work = Path(tmp)
        summary = real_summary(args.result, work)
        assert summary["tasks"] == tasks, (summary["tasks"], tasks)
        variants = variant_summaries(summary, VARIANTS)
        rows = variant_rows(variants, work, tenant)
        with batch_stack(work, args.jobs + args.finishes) as stack:
            database = engine(stack.env["BFIELDS_DATABASE_URL"])
            scene = work / "scene"
            shutil.copytree(SAMPLE, scene)
            (scene / "splat.ply").symlink_to(scene / "point_cloud.ply")
            with _client(stack, tenant, 600) as client:
                scene_id = upload(client, scene)
            scenes = register_scenes(database, tenant, scene_id, args.scenes)
            total = args.jobs + args.finishes
            items = [{"scene_id": scenes[i % len(scenes)], "tasks": tasks} for i in range(total)]
            with _client(stack, tenant, 1800) as client:
                t0 = time.monotonic()
                batch = _ok(client.post("/v1/batches", json={"items": items})).json()
                submit_s = time.monotonic() - t0
                print(f"batch of {total:,} jobs submitted in {submit_s:.1f} s")
                jobs = _job_ids(client, batch["id"])
            assert len(jobs) == total
            fill_s = fill(database, jobs[args.finishes :], rows, tenant)
            # after the fill: a finish writes into the full table and its indexes
            write = measure_write(stack, stack.s3.store(), jobs[: args.finishes], variants, tenant)
            n_rows = settle(database)
            with _client(stack, tenant, 600) as client:
                reads = measure_reads(client, batch["id"], tasks[0], total, args.reads, args.min_probability)
            reads["explain"] = explain_reads(
                database, tenant, batch["id"], tasks[0], total, args.min_probability
            )
            with _client(stack, tenant, 600) as client:
                export = measure_export(stack, client, batch["id"], args.idle_s)
            assert export["export_rows"] == n_rows, (export["export_rows"], n_rows)
            figures: dict[str, Any] = {
                "jobs": total, "scenes": len(scenes), "rows": n_rows, "tasks": len(tasks),
                "objects_per_task": OBJECTS, "rows_written_directly": True, "submit_s": submit_s,
                "fill_s": fill_s, **write, **reads, **export, "targets": TARGETS,
                "load_before": load_before, "load_after": [round(x, 2) for x in os.getloadavg()],
                "cpus": os.cpu_count(),
            }  # fmt: skip
            database.dispose()
            url = stack.env["BFIELDS_DATABASE_URL"]
        from tests.integration.fixtures.postgres import drop_database

        drop_database(url)
    report(figures)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
