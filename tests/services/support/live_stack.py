"""Run schemathesis against the live OpenAPI of a real stack (CI stage `.ci/schemathesis.sh`).

Starts what the service tests start (a private redis-server, `rclone serve s3`, uvicorn with the
API; no workers: submitted jobs stay queued), uploads one valid scene so ids in examples can hit
a real object, then runs ``st run`` with an API key and the checks that matter here: no 5xx and
responses (status, content type, headers, body) that match the schema. Prints the case count and
exits with schemathesis' status.

    python -m tests.services.support.live_stack --max-examples 40
"""

from __future__ import annotations

import argparse
import re
import secrets
import subprocess
import sys
import tempfile
from pathlib import Path

from tests.integration.fixtures.processes import venv_bin
from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.s3_server import S3Server
from tests.integration.fixtures.services import ApiServer, build_service_env
from tests.services.conftest import SERVICE_ENV, scene_form

from .scene_factory import make_scene

CHECKS = (
    "not_a_server_error,status_code_conformance,content_type_conformance,"
    "response_headers_conformance,response_schema_conformance"
)


def run(max_examples: int, max_time_s: int, workdir: Path) -> int:
    redis_server = RedisServer(workdir / "redis").start()
    s3 = S3Server(workdir / "s3").start()
    keys = {"tenant-st": "key-st-" + secrets.token_urlsafe(16)}
    env = {**build_service_env(workdir / "env", redis_server.url(), s3.env(), keys), **SERVICE_ENV}
    env["BFIELDS_GPU_QUEUE"], env["BFIELDS_CPU_QUEUE"] = "st-gpu", "st-cpu"  # nobody consumes them
    api = ApiServer(env=env, log_dir=workdir / "api", keys=keys).start()
    try:
        with api.client("tenant-st") as client:
            scene = make_scene(workdir / "scene")
            resp = client.post("/v1/scenes", files=scene_form(scene), data={"name": "schemathesis"})
            resp.raise_for_status()
            ids = {"scene_id": resp.json()["id"]}
            job = client.post("/v1/jobs", json={"scene_id": ids["scene_id"], "tasks": ["red blob"]})
            ids["job_id"] = job.raise_for_status().json()["id"]
            batch = client.post(
                "/v1/batches", json={"items": [{"scene_id": ids["scene_id"], "tasks": ["a"]}]}
            )
            ids["batch_id"] = batch.raise_for_status().json()["id"]
        # Path ids point at real objects (otherwise nearly every case is a 404 before any logic);
        # bodies and queries stay fully generated.
        config = workdir / "schemathesis.toml"
        config.write_text("[parameters]\n" + "".join(f'"path.{k}" = "{v}"\n' for k, v in ids.items()))
        st = venv_bin("st") or "st"
        argv = [
            st, "--config-file", str(config), "run", f"{api.base_url}/openapi.json",
            "-H", f"X-API-Key: {keys['tenant-st']}",
            "--checks", CHECKS,
            "--max-examples", str(max_examples),
            "--max-time", str(max_time_s),
            "--phases", "examples,coverage,fuzzing",
            # One worker: CPython 3.11 converts ASTs with interpreter-wide recursion state, and
            # hypothesis describes lambdas through `ast` in each worker thread; two threads doing
            # so at once fail the run with "AST constructor recursion depth mismatch" (CI, c2fa79b).
            "--workers", "1",
            "--seed", "12",
            "--request-timeout", "30",
            "--suppress-health-check", "all",
            ]  # fmt: skip
        proc = subprocess.run(argv, check=False, capture_output=True, text=True)
        print(proc.stdout, proc.stderr, sep="\n")
        code = proc.returncode
        found = re.search(r"(\d+) generated", proc.stdout)
        print(f"schemathesis: {found.group(1) if found else 'unknown'} cases, exit status {code}")
        if code != 0:
            print(api.process.log_tail(6000) if api.process else "", file=sys.stderr)
        return code
    finally:
        api.stop()
        s3.stop()
        redis_server.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-examples", type=int, default=40, help="cases per operation and phase")
    parser.add_argument("--max-time", type=int, default=240, help="time budget of the run, seconds")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bfields-st-") as tmp:
        return run(args.max_examples, args.max_time, Path(tmp))


if __name__ == "__main__":
    sys.exit(main())
