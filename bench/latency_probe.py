"""Another tenant's request latency, measured from a process of its own.

`bench_batch_ops --other-tenant` starts this beside its own client: a probe thread inside the bench
would share the bench's interpreter lock with tenant A's client, which encodes a 5,000-item body and
decodes a 5,000-job answer, so A's client work would be counted as B's latency. A real other tenant
is another program. The probe sends `GET /v1/jobs?limit=20` every `--interval-s` until its stdin
closes and prints one line per request, `START_MONOTONIC DURATION_S` (CLOCK_MONOTONIC is one clock
for every process on the machine, so the bench can place each request against its own submits).

    python -m bench.latency_probe URL API_KEY [--interval-s 0.05]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import httpx


def probe(url: str, api_key: str, interval_s: float, stop: threading.Event) -> None:
    """Request, time and print until `stop` is set; a failed request ends the probe with its error."""
    with httpx.Client(base_url=url, headers={"X-API-Key": api_key}, timeout=60) as client:
        while not stop.is_set():
            start = time.monotonic()
            resp = client.get("/v1/jobs", params={"limit": 20})
            took = time.monotonic() - start
            resp.raise_for_status()
            print(f"{start:.6f} {took:.6f}", flush=True)
            time.sleep(interval_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("url")
    parser.add_argument("api_key")
    parser.add_argument("--interval-s", type=float, default=0.05)
    args = parser.parse_args()
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    probe(args.url, args.api_key, args.interval_s, stop)


if __name__ == "__main__":
    main()
