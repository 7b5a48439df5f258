"""The worker and API fixtures run real processes: start, ping, SIGKILL, restart, isolated env."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest
from celery import Celery

from tests.integration.fixtures.processes import isolated_env
from tests.integration.fixtures.services import ApiServer, WorkerPool, celery_ping

MINI_CELERY = "tests.integration.apps.mini_celery"


@pytest.fixture
def env(tmp_path: Path, redis_url: str) -> dict[str, str]:
    return isolated_env(tmp_path / "env", {"BFIELDS_REDIS_URL": redis_url})


def _client(redis_url: str) -> Celery:
    client = Celery("probe", broker=redis_url, backend=redis_url)
    client.conf.update(task_serializer="json", accept_content=["json"], result_serializer="json")
    return client


def _dead(pid: int, timeout_s: float = 5.0) -> bool:
    """True once `pid` is gone or a zombie (an orphan may wait for a reaper that never comes)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except FileNotFoundError:
            return True
        if state in ("Z", "X"):
            return True
        time.sleep(0.05)
    return False


def test_isolated_env_scrubs_user_configuration(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BFIELDS_S3_SECRET_ACCESS_KEY", "from-the-developer-shell")
    monkeypatch.setenv("AWS_PROFILE", "prod")
    env = isolated_env(tmp_path, {"BFIELDS_REDIS_URL": "redis://x/1"})
    assert "BFIELDS_S3_SECRET_ACCESS_KEY" not in env and "AWS_PROFILE" not in env
    for var in ("HOME", "XDG_CACHE_HOME", "YOLO_CONFIG_DIR", "TMPDIR", "HF_HOME"):
        assert Path(env[var]).is_dir() and Path(env[var]).is_relative_to(tmp_path)
    assert env["BFIELDS_REDIS_URL"] == "redis://x/1" and env["HF_HUB_OFFLINE"] == "1"


def test_worker_start_run_crash_restart(tmp_path: Path, redis_url: str, env: dict[str, str]) -> None:
    pool = WorkerPool(broker_url=redis_url, env=env, log_dir=tmp_path / "logs", app=MINI_CELERY)
    client = _client(redis_url)
    try:
        worker = pool.start("cpu", name="cpu-a", pool="prefork")
        assert celery_ping(redis_url, worker.node)
        result = client.send_task("mini.echo", args=["hi"], queue="cpu").get(timeout=20)
        assert result["value"] == "hi" and result["home"] == env["HOME"]
        first_pid = result["pid"]

        worker.kill()  # SIGKILL the whole group: the prefork child goes too
        assert not worker.alive
        assert _dead(int(first_pid))  # the pool child did not outlive its parent
        assert not celery_ping(redis_url, worker.node, timeout_s=0.5)

        pending = client.send_task("mini.echo", args=["queued while down"], queue="cpu")
        worker.start()
        assert pending.get(timeout=20)["value"] == "queued while down"
        assert "ready." in worker.log_text()
    finally:
        pool.stop_all()
        client.close()
    assert not pool.workers


def test_two_queues_are_separate(tmp_path: Path, redis_url: str, env: dict[str, str]) -> None:
    pool = WorkerPool(broker_url=redis_url, env=env, log_dir=tmp_path / "logs", app=MINI_CELERY)
    client = _client(redis_url)
    try:
        gpu = pool.start("gpu")
        cpu = pool.start("cpu")
        assert gpu.node != cpu.node
        gpu_pid = client.send_task("mini.echo", args=["g"], queue="gpu").get(timeout=20)["pid"]
        cpu_pid = client.send_task("mini.echo", args=["c"], queue="cpu").get(timeout=20)["pid"]
        assert gpu_pid == str(gpu.process.pid) and cpu_pid == str(cpu.process.pid)  # solo pool: in-process
    finally:
        pool.stop_all()
        client.close()


def test_api_server_fixture_mechanics(tmp_path: Path, env: dict[str, str]) -> None:
    server = ApiServer(
        env=env, log_dir=tmp_path, keys={"tenant-a": "k"}, app="tests.integration.apps.mini_asgi:app"
    )
    server.start()
    try:
        body = httpx.get(server.base_url + "/healthz").json()
        assert body["redis"] == env["BFIELDS_REDIS_URL"] and body["home"] == env["HOME"]
        assert server.headers("tenant-a") == {"X-API-Key": "k"}
    finally:
        server.stop()
    with pytest.raises(httpx.ConnectError):
        httpx.get(server.base_url + "/healthz", timeout=1)


def test_api_server_start_failure_shows_log(tmp_path: Path, env: dict[str, str]) -> None:
    server = ApiServer(env=env, log_dir=tmp_path, keys={}, app="tests.integration.apps.no_such_module:app")
    with pytest.raises(RuntimeError, match="no_such_module"):
        server.start(timeout_s=30)
