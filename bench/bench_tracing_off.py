"""What tracing costs when it is off (issue 44): the submit route through a real stack, and the
helpers the hot paths call, against the code before tracing existed.

Two measurements:

- ``micro``: nanoseconds per call of what the request, dispatch and stage paths now call with
  tracing off (`tracing.job_span` entered and left, `current_traceparent`, `annotate`,
  `logs.log_context`), beside an empty loop; in process, no server.
- ``submit``: a timed loop of ``POST /v1/jobs`` (one job each, no workers: every job waits)
  through a private stack (redis-server, ``rclone serve s3``, a PostgreSQL database of its own,
  uvicorn with its control process), from the tree on ``PYTHONPATH``: median and p90 of
  `--requests` submissions after `--warmup`. ``--compare BASE`` runs it alternately from a
  checkout of the code before the change and from this tree (`--rounds` each), and prints both;
  ``--tracing file:PATH`` (or otlp, ...) sets BFIELDS_TRACING on the stack, for the cost when on.

Usage (repository root; BASE: e.g. ``git archive <commit> | tar -x -C /tmp/base`` plus the
``bayesian_fields_service -> services`` link):

    python bench/bench_tracing_off.py micro
    python bench/bench_tracing_off.py submit --requests 300
    python bench/bench_tracing_off.py submit --compare /tmp/base --rounds 2
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
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
KEYS = {"tenant-a": "key-a"}
TASKS = ["red blob", "green blob"]


def micro(n: int) -> dict[str, float]:
    """ns per call of each off-path helper (best of 5 runs of `n` calls)."""
    from bayesian_fields_service.observability import logs, tracing

    assert not tracing.enabled(), "tracing must be off for this measurement"
    attributes = {"bfields.job_id": "j_x", "bfields.tenant": "t"}

    def empty() -> None:
        for _ in range(n):
            pass

    def span() -> None:
        for _ in range(n):
            with tracing.job_span("stage perceive", attributes) as handle:
                handle.set_attributes(attributes)

    def traceparent() -> None:
        for _ in range(n):
            tracing.current_traceparent()

    def annotate() -> None:
        for _ in range(n):
            tracing.annotate(attributes)

    def context() -> None:
        for _ in range(n):
            with logs.log_context(job_id="j_x", tenant="t", stage="fuse"):
                pass

    out = {}
    for name, fn in {"empty loop": empty, "job_span": span, "current_traceparent": traceparent,
                     "annotate": annotate, "log_context": context}.items():  # fmt: skip
        best = min(_timed(fn) for _ in range(5))
        out[name] = best / n * 1e9
    return out


def _timed(fn: Any) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def submit(requests: int, warmup: int, tracing: str | None) -> dict[str, float]:
    """Seconds per ``POST /v1/jobs`` through a private stack of the tree on PYTHONPATH."""
    from tests.integration.fixtures.s3_server import S3Server
    from tests.services.support.private_stack import PrivateStack, upload
    from tests.services.support.scene_factory import make_scene

    extra = {"BFIELDS_MAX_WAITING_JOBS_PER_TENANT": str(10 * (requests + warmup))}
    if tracing:
        extra["BFIELDS_TRACING"] = tracing
    with tempfile.TemporaryDirectory(prefix="bench-tracing-") as tmp:
        s3 = S3Server(Path(tmp) / "s3").start()
        stack = PrivateStack(Path(tmp), s3.env(), dict(KEYS), extra)
        try:
            stack.start()
            assert stack.api is not None
            with stack.api.client("tenant-a") as client:
                scene_id = upload(client, make_scene(Path(tmp) / "scene"))
                body = {"scene_id": scene_id, "tasks": TASKS, "parameters": {"max_frames": 4}}
                took = []
                for i in range(warmup + requests):
                    t0 = time.perf_counter()
                    resp = client.post("/v1/jobs", json=body)
                    if resp.status_code != 202:
                        raise SystemExit(f"POST /v1/jobs: {resp.status_code} {resp.text[:300]}")
                    if i >= warmup:
                        took.append(time.perf_counter() - t0)
        finally:
            stack.stop()
            s3.stop()
    took.sort()
    return {"median_ms": statistics.median(took) * 1e3, "p90_ms": took[int(0.9 * len(took))] * 1e3,
            "n": len(took), "load_1min": os.getloadavg()[0]}  # fmt: skip


def _in_tree(tree: Path, args: argparse.Namespace) -> dict[str, float]:
    """`submit` run by this script in a subprocess whose PYTHONPATH is `tree` (its stack too)."""
    cmd = [sys.executable, __file__, "submit", "--requests", str(args.requests), "--warmup",
           str(args.warmup), "--json-out"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"submit in {tree} failed:\n{done.stderr[-3000:]}")
    return dict(json.loads(done.stdout.splitlines()[-1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    m = sub.add_parser("micro")
    m.add_argument("-n", type=int, default=200_000)
    s = sub.add_parser("submit")
    s.add_argument("--requests", type=int, default=300)
    s.add_argument("--warmup", type=int, default=30)
    s.add_argument("--tracing", help="BFIELDS_TRACING of the stack (default: off)")
    s.add_argument("--compare", type=Path, help="a checkout of the code before tracing")
    s.add_argument("--rounds", type=int, default=2)
    s.add_argument("--json-out", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.what == "micro":
        for name, ns in micro(args.n).items():
            print(f"{name:>20}: {ns:8.1f} ns/call")
        return
    if args.compare is None:
        figures = submit(args.requests, args.warmup, args.tracing)
        print(json.dumps(figures) if args.json_out else
              f"POST /v1/jobs: median {figures['median_ms']:.2f} ms, p90 {figures['p90_ms']:.2f} ms "
              f"(n={figures['n']}, load {figures['load_1min']:.1f})")  # fmt: skip
        return
    results: dict[str, list[dict[str, float]]] = {"before": [], "after (tracing off)": []}
    for _ in range(args.rounds):
        results["before"].append(_in_tree(args.compare, args))
        results["after (tracing off)"].append(_in_tree(ROOT, args))
    for name, rounds in results.items():
        medians = ", ".join(f"{r['median_ms']:.2f}" for r in rounds)
        p90s = ", ".join(f"{r['p90_ms']:.2f}" for r in rounds)
        print(f"{name:>20}: median ms per round {medians}; p90 {p90s}")


if __name__ == "__main__":
    main()
