"""A service stack of its own for a test module: a private redis-server, an API and workers on it
(the session's S3 server is shared; keys are per scene/job id, so nothing collides).

Why not the session fixtures: workers started by other modules (a 'rescuer' kept alive, their
recovery scans) consume the shared queues and would run this module's jobs with other settings,
so a test of worker disk or crash handling could pass for the wrong reason.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import redis

from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.services import ApiServer, WorkerPool, build_service_env


@dataclass
class PrivateStack:
    tmp: Path
    s3_env: Mapping[str, str]
    keys: dict[str, str]
    extra_env: dict[str, str] = field(default_factory=dict)
    redis_server: RedisServer | None = None
    api: ApiServer | None = None
    pool: WorkerPool | None = None
    env: dict[str, str] = field(default_factory=dict)

    def start(self, *, api: bool = True) -> PrivateStack:
        self.redis_server = RedisServer(self.tmp / "redis").start()
        self.env = build_service_env(
            self.tmp / "env", self.redis_server.url(), self.s3_env, self.keys, self.extra_env
        )
        self.pool = WorkerPool(broker_url=self.redis_server.url(), env=self.env, log_dir=self.tmp / "workers")
        if api:
            self.api = ApiServer(env=self.env, log_dir=self.tmp / "api", keys=dict(self.keys)).start()
        return self

    @property
    def redis(self) -> redis.Redis:
        assert self.redis_server is not None
        return redis.Redis.from_url(self.redis_server.url())

    @property
    def temp_dir(self) -> Path:
        """TMPDIR of every process of the stack (the API's upload temp folders live here)."""
        return Path(self.env["TMPDIR"])

    def stop(self) -> None:
        if self.pool is not None:
            self.pool.stop_all()
        if self.api is not None:
            self.api.stop()
        if self.redis_server is not None:
            self.redis_server.stop()


def wait_job(client: httpx.Client, job_id: str, timeout_s: float = 240) -> dict:
    deadline = time.monotonic() + timeout_s
    job: dict = {}
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.3)
    raise AssertionError(f"job {job_id} did not finish in {timeout_s}s: {job}")


def upload(client: httpx.Client, folder: Path) -> str:
    from tests.services.conftest import scene_form

    resp = client.post("/v1/scenes", files=scene_form(folder))
    assert resp.status_code == 201, resp.text
    return str(resp.json()["id"])


def pool_children(pid: int) -> list[int]:
    """Pids of the direct children of `pid` (a prefork worker's pool processes), from /proc."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out
