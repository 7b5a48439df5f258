"""Prove the shipped dashboard's queries and alert rules (issue 44, items 2 and 7): a real
Prometheus (Debian's `prometheus` package, run as this script's own process on a free port, with a
temporary config and data folder) scrapes the real stack's `/metrics` while a small fleet runs,
and every panel's PromQL is asked of it, mid-fleet and after; the alert rules are loaded too and
their states read back.

The stack is the service tests' (`PrivateStack`: a private redis-server, a records database of its
own, one uvicorn API with its control process, an rclone S3 server) with real Celery workers (one
prefork worker per queue, on the CPU). Jobs are the service tests' tiny synthetic scene
(`tests/services/support/scene_factory.py`), `--jobs` of them from two tenants, each with its own
task list (perception computed once per scene, the rest from its cache).

Writes bench/results/observability-fleet-<date>.json (every answer) and .md (one table per
snapshot: panel, query, answer). Usage, from the repository root:
    PYTHONPATH=$PWD python -m bench.observability_fleet --jobs 12
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import time
from datetime import UTC, datetime
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import httpx
import yaml

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results"
SCRAPE_S = 2


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_prometheus(workdir: Path, api_port: int, token: str) -> tuple[subprocess.Popen[bytes], str]:
    """A Prometheus of this run's own: scrapes the API every 2 s with the metrics token and
    evaluates deploy/prometheus/alerts.yaml as often."""
    exe = shutil.which("prometheus")
    if exe is None:
        raise SystemExit("prometheus is not on PATH (Debian: apt-get install prometheus)")
    port = _free_port()
    config = {
        "global": {"scrape_interval": f"{SCRAPE_S}s", "evaluation_interval": f"{SCRAPE_S}s"},
        "rule_files": [str(REPO / "deploy" / "prometheus" / "alerts.yaml")],
        "scrape_configs": [{
            "job_name": "bfields-api",
            "metrics_path": "/metrics",
            "authorization": {"type": "Bearer", "credentials": token},
            "static_configs": [{"targets": [f"127.0.0.1:{api_port}"]}],
        }],
    }  # fmt: skip
    (workdir / "prometheus.yml").write_text(yaml.safe_dump(config))
    log = (workdir / "prometheus.log").open("wb")
    proc = subprocess.Popen(
        [exe, f"--config.file={workdir / 'prometheus.yml'}", f"--storage.tsdb.path={workdir / 'tsdb'}",
         f"--web.listen-address=127.0.0.1:{port}", "--log.level=warn"],
        stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        try:
            if httpx.get(f"{url}/-/ready", timeout=1).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"prometheus did not start; see {workdir / 'prometheus.log'}")
        time.sleep(0.5)


def query(prom: str, expr: str) -> list[dict[str, Any]]:
    """The instant vector `expr` evaluates to now: [{labels, value}]."""
    resp = httpx.get(f"{prom}/api/v1/query", params={"query": expr}, timeout=30).json()
    if resp["status"] != "success":
        raise RuntimeError(f"{expr}: {resp}")
    data = resp["data"]
    if data["resultType"] == "scalar":
        return [{"labels": {}, "value": data["result"][1]}]
    return [{"labels": r["metric"], "value": r["value"][1]} for r in data["result"]]


def snapshot(prom: str, name: str) -> dict[str, Any]:
    """Every dashboard query and every alert's state, now."""
    from tests.support.observability import dashboard_queries

    panels = [
        {"panel": title, "query": expr, "answer": query(prom, expr)} for title, expr in dashboard_queries()
    ]
    rules = httpx.get(f"{prom}/api/v1/rules", timeout=30).json()["data"]["groups"]
    alerts = [{"alert": r["name"], "state": r["state"], "health": r["health"], "last_error": r.get("lastError", "")}
              for g in rules for r in g["rules"]]  # fmt: skip
    targets = httpx.get(f"{prom}/api/v1/targets", timeout=30).json()["data"]["activeTargets"]
    return {
        "name": name,
        "at": datetime.now(UTC).isoformat(timespec="seconds"),
        "targets": [
            {"url": t["scrapeUrl"], "health": t["health"], "last_error": t["lastError"]} for t in targets
        ],
        "panels": panels,
        "alerts": alerts,
    }


def _fmt(answer: list[dict[str, Any]]) -> str:
    if not answer:
        return "(empty)"
    parts = []
    for a in answer:
        labels = ",".join(f"{k}={v}" for k, v in sorted(a["labels"].items()) if k not in ("instance", "job"))
        value = float(a["value"])
        shown = f"{value:.4g}" if value == value else "NaN"
        parts.append(f"{labels}: {shown}" if labels else shown)
    return "; ".join(parts)


def markdown(report: dict[str, Any]) -> str:
    lines = [f"# Dashboard queries against a real Prometheus ({report['started']})", "",
             f"Fleet: {report['fleet']}", "",
             f"Machine: {report['cpus']} CPUs shared with other work, load average before the run "
             f"{report['load_before'][0]:.1f}. The panels' ranges are the dashboard's own ([5m], [30m]); "
             "Prometheus scraped the API every 2 s.", ""]  # fmt: skip
    for snap in report["snapshots"]:
        lines += [f"## {snap['name']} ({snap['at']})", "",
                  "targets: " + ", ".join(f"{t['url']} {t['health']}" for t in snap["targets"]), "",
                  "| panel | query | answer |", "|---|---|---|"]  # fmt: skip
        for p in snap["panels"]:
            lines.append(f"| {p['panel']} | `{p['query']}` | {_fmt(p['answer'])} |")
        lines += ["", "| alert | state | health |", "|---|---|---|"]
        lines += [f"| {a['alert']} | {a['state']} | {a['health']} |" for a in snap["alerts"]]
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--jobs", type=int, default=12)
    p.add_argument("--max-frames", type=int, default=4)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument(
        "--keep", type=Path, default=None, help="run in this folder and keep it (the processes' logs)"
    )
    args = p.parse_args()

    from tests.integration.fixtures.s3_server import S3Server
    from tests.integration.fixtures.services import METRICS_TOKEN
    from tests.services.conftest import SERVICE_ENV
    from tests.services.support.private_stack import PrivateStack, upload, wait_job
    from tests.services.support.scene_factory import make_scene

    keys = {"tenant-a": "key-a-observability", "tenant-b": "key-b-observability"}
    fast_recovery = {k: v for k, v in SERVICE_ENV.items() if "LOCK_TTL" in k or "RECOVERY" in k}
    started = datetime.now(UTC)
    report: dict[str, Any] = {"started": started.isoformat(timespec="seconds"), "snapshots": [],
                              "cpus": os.cpu_count(), "load_before": os.getloadavg()}  # fmt: skip
    with TemporaryDirectory(prefix="bfields-observability-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        s3 = S3Server(work / "s3").start()
        stack = PrivateStack(work, s3.env(), keys, fast_recovery)
        prom_proc = None
        try:
            stack.start()
            assert stack.api is not None and stack.pool is not None
            for queue in ("gpu", "cpu"):
                stack.pool.start(queue, name=f"{queue}-1", pool="prefork", timeout_s=180)
            (work / "prom").mkdir()
            prom_proc, prom = start_prometheus(work / "prom", stack.api.port, METRICS_TOKEN)
            scene = make_scene(work / "scene")
            ids: list[tuple[str, str]] = []
            t0 = time.monotonic()
            with stack.api.client("tenant-a") as a, stack.api.client("tenant-b") as b:
                scene_ids = {"tenant-a": upload(a, scene), "tenant-b": upload(b, scene)}
                clients = {"tenant-a": a, "tenant-b": b}
                for i in range(args.jobs):
                    tenant = "tenant-a" if i % 3 else "tenant-b"
                    body = {"scene_id": scene_ids[tenant], "tasks": [f"red blob {i}"],
                            "parameters": {"max_frames": args.max_frames}}  # fmt: skip
                    resp = clients[tenant].post("/v1/jobs", json=body)
                    resp.raise_for_status()
                    ids.append((tenant, resp.json()["id"]))
                while (
                    sum(  # mid-fleet: a third of the jobs ended, the rest queued or running
                        clients[t].get(f"/v1/jobs/{j}").json()["state"]
                        in ("succeeded", "failed", "cancelled")
                        for t, j in ids
                    )
                    < len(ids) // 3
                ):
                    time.sleep(1)
                time.sleep(2 * SCRAPE_S)
                report["snapshots"].append(snapshot(prom, "mid-fleet"))
                records = [wait_job(clients[tenant], job_id, timeout_s=900) for tenant, job_id in ids]
            took = time.monotonic() - t0
            time.sleep(4 * SCRAPE_S)  # the last stage ends scraped
            report["snapshots"].append(snapshot(prom, "after the fleet"))
            states = {s: sum(r["state"] == s for r in records) for s in {r["state"] for r in records}}
            report["fleet"] = (f"{args.jobs} jobs (tenant-a {sum(t == 'tenant-a' for t, _ in ids)}, tenant-b "
                               f"{sum(t == 'tenant-b' for t, _ in ids)}) of the tiny synthetic scene, "
                               f"max_frames {args.max_frames}, 1 gpu-queue + 1 cpu-queue prefork worker on "
                               f"the CPU; {states}; {took:.0f} s from the first submission to the last end")  # fmt: skip
        finally:
            if prom_proc is not None:
                prom_proc.terminate()
                prom_proc.wait(timeout=30)
            stack.stop()
            s3.stop()
    out = args.out or RESULTS / f"observability-fleet-{started:%Y%m%d}.json"
    out.write_text(json.dumps(report, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(report))
    print(markdown(report))
    print(f"written: {out} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
