"""What Celery's own mechanisms give for fair share (issue 20, item 2: "use Celery's own mechanisms
where they give this guarantee (measure it), a dispatcher on Redis where they do not").

Two mechanisms are measured on a real Redis broker with a real solo worker (prefetch 1, late acks,
as the service's workers run), with a task that only records who it ran for:

1. **Message priority** (the Redis transport's priority lists): tenant A's 12 bulk messages are
   queued, then tenant B's one interactive message, then B's 12 bulk messages. Priority lets the
   interactive message overtake A's backlog, but B's bulk messages still wait behind all of A's
   (FIFO within a priority): no share between tenants.
2. **One queue per tenant** consumed by every worker (`-Q a,b`): the transport polls the queues
   in rotation, so two backlogged tenants alternate 1:1. That is fair share with equal weights
   only: a weight (2:1) cannot be expressed, every new tenant needs `add_consumer` on every
   worker, and a per-tenant bound on running jobs is not enforced.

Run: `python -m bench.celery_fairness` (starts its own redis-server and worker; ~30 s). Prints the
execution order and Jain's index of A's and B's share while both were backlogged.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import redis
from celery import Celery

BROKER = os.environ.get("BFIELDS_BENCH_BROKER", "redis://127.0.0.1:6379/15")
RECORD_KEY = "bench:celery-fairness:order"
PER_TENANT = 12

app = Celery("celery_fairness", broker=BROKER)
app.conf.update(
    task_acks_late=True,
    worker_prefetch_multiplier=1,
    # the Redis transport's defaults, written out: four priority lists per queue, and several
    # queues polled in rotation ("round_robin"), which is what could give tenants a share
    broker_transport_options={"priority_steps": [0, 3, 6, 9], "queue_order_strategy": "round_robin"},
)


@app.task(name="bench.record")
def record(tenant: str, seq: int) -> None:
    """Append who ran to the record list; sleeps a little so the worker is the bottleneck."""
    time.sleep(0.05)
    redis.Redis.from_url(BROKER).rpush(RECORD_KEY, f"{tenant}{seq}")


def jain(amounts: list[float]) -> float:
    """Jain's fairness index: 1 when all equal, 1/n when one takes everything."""
    return sum(amounts) ** 2 / (len(amounts) * sum(a * a for a in amounts)) if any(amounts) else 1.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _run_worker(queues: str, env: dict[str, str], expected: int, client: redis.Redis) -> list[str]:
    """Start a solo worker on `queues`, wait until it recorded `expected` runs, stop it."""
    celery = str(Path(sys.executable).with_name("celery"))
    argv = [celery, "-A", "bench.celery_fairness", "worker", "-Q", queues, "--pool", "solo",
            "--without-gossip", "--without-mingle", "--loglevel", "WARNING"]  # fmt: skip
    worker = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while client.llen(RECORD_KEY) < expected:
            if time.monotonic() > deadline:
                raise RuntimeError(f"worker ran {client.llen(RECORD_KEY)} of {expected} tasks in 120 s")
            time.sleep(0.1)
    finally:
        worker.terminate()
        worker.wait(30)
    return [v.decode() for v in client.lrange(RECORD_KEY, 0, -1)]


def _share_while_both_waiting(order: list[str]) -> tuple[int, int]:
    """Runs of A and B up to the point where one of them had run all of its bulk messages."""
    a = b = 0
    for item in order:
        if item.startswith("A"):
            a += 1
        elif item.startswith("B") and not item.startswith("B-interactive"):
            b += 1
        if a == PER_TENANT or b == PER_TENANT:
            break
    return a, b


def main() -> int:
    global BROKER
    server = shutil.which("redis-server")
    if server is None:
        print("redis-server not found")
        return 1
    port = _free_port()
    tmp = tempfile.mkdtemp(prefix="celery-fairness-")
    proc = subprocess.Popen([server, "--port", str(port), "--save", "", "--dir", tmp],
                            stdout=subprocess.DEVNULL)  # fmt: skip
    BROKER = f"redis://127.0.0.1:{port}/0"
    app.conf.broker_url = BROKER
    env = {**os.environ, "BFIELDS_BENCH_BROKER": BROKER, "PYTHONPATH": str(Path(__file__).parents[1])}
    client = redis.Redis.from_url(BROKER)
    try:
        while True:
            try:
                client.ping()
                break
            except redis.ConnectionError:
                time.sleep(0.05)
        # 1. priorities on one queue
        for i in range(PER_TENANT):
            record.apply_async(("A", i), queue="shared", priority=9)
        record.apply_async(("B-interactive", 0), queue="shared", priority=0)
        for i in range(PER_TENANT):
            record.apply_async(("B", i), queue="shared", priority=9)
        order = _run_worker("shared", env, 2 * PER_TENANT + 1, client)
        a, b = _share_while_both_waiting(order)
        print("1. one queue, priorities (A: 12 bulk, then B: 1 interactive + 12 bulk)")
        print("   order:", " ".join(order))
        print(f"   B's interactive job ran at position {order.index('B-interactive0') + 1}; while both "
              f"were backlogged A ran {a}, B {b} bulk jobs: Jain {jain([a, b]):.3f}")  # fmt: skip
        client.delete(RECORD_KEY)
        # 2. one queue per tenant, one worker consuming both
        for i in range(PER_TENANT):
            record.apply_async(("A", i), queue="tenant-a")
        for i in range(PER_TENANT):
            record.apply_async(("B", i), queue="tenant-b")
        order = _run_worker("tenant-a,tenant-b", env, 2 * PER_TENANT, client)
        a, b = _share_while_both_waiting(order)
        print("2. a queue per tenant, one worker on both (A: 12 queued first, then B: 12)")
        print("   order:", " ".join(order))
        print(f"   while both were backlogged A ran {a}, B {b}: Jain {jain([a, b]):.3f} "
              "(equal weights only; no weights, no per-tenant running bound)")  # fmt: skip
    finally:
        client.close()
        proc.terminate()
        proc.wait(10)
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
