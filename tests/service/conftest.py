"""Service tests run against real processes: the infra fixtures (Redis, rclone S3, Celery workers,
uvicorn) plus an API started with small limits so the limit checks are cheap to exercise."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.conftest import *  # noqa: F403 - the integration fixtures, found by name
from tests.integration.fixtures.services import ApiServer

from .scene_factory import make_scene

#: Limits of the test API, small enough to trip with tiny uploads.
MAX_UPLOAD = 2_000_000
MAX_EXPANDED = 4_000_000
MAX_MEMBERS = 100

SERVICE_ENV = {
    "BFIELDS_MAX_UPLOAD_BYTES": str(MAX_UPLOAD),
    "BFIELDS_MAX_ARCHIVE_UNCOMPRESSED_BYTES": str(MAX_EXPANDED),
    "BFIELDS_MAX_ARCHIVE_MEMBERS": str(MAX_MEMBERS),
    "BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT": "100",
    # fast crash recovery: a dead worker's stage lock expires after 6 s, scans every 2 s
    "BFIELDS_STAGE_LOCK_TTL_S": "6",
    "BFIELDS_RECOVERY_INTERVAL_S": "2",
    "BFIELDS_RECOVERY_GRACE_S": "3",
    # Below the defaults (256 / 200) so the tests prove the configured limits are the ones applied.
    "BFIELDS_MAX_TASKS": "20",
    "BFIELDS_MAX_TASK_CHARS": "60",
    # Lets the race tests hold a scene route at a named point (inert unless a test arms one).
    "BFIELDS_TEST_PAUSE_POINTS": "true",
}


@pytest.fixture(scope="session")
def svc_env(service_env: dict[str, str]) -> dict[str, str]:
    return {**service_env, **SERVICE_ENV}


@pytest.fixture(scope="session")
def api(
    tmp_path_factory: pytest.TempPathFactory, svc_env: dict[str, str], test_api_keys: dict[str, str]
) -> Iterator[ApiServer]:
    server = ApiServer(
        env=svc_env, log_dir=tmp_path_factory.mktemp("svc-api"), keys=dict(test_api_keys)
    ).start()
    yield server
    server.stop()


@pytest.fixture
def client_a(api: ApiServer) -> Iterator[httpx.Client]:
    with api.client("tenant-a") as client:
        yield client


@pytest.fixture
def client_b(api: ApiServer) -> Iterator[httpx.Client]:
    with api.client("tenant-b") as client:
        yield client


@pytest.fixture(scope="session")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_scene(tmp_path_factory.mktemp("scene") / "blobs")


def scene_form(folder: Path, *, images_zip: bytes | None = None) -> list[tuple[str, tuple[str, bytes]]]:
    """The multipart form of a scene folder: images as files, or the given zip."""
    files = [
        ("splat", ("splat.ply", (folder / "splat.ply").read_bytes())),
        ("cameras", ("transforms.json", (folder / "transforms.json").read_bytes())),
    ]
    if images_zip is not None:
        files.append(("images", ("images.zip", images_zip)))
    else:
        files += [("images", (p.name, p.read_bytes())) for p in sorted((folder / "images").iterdir())]
    return files


@pytest.fixture(scope="session")
def stored_scene(api: ApiServer, scene_dir: Path) -> dict:
    """A scene of tenant-a uploaded once per session (the 'earlier data' bad uploads must not touch)."""
    with api.client("tenant-a") as client:
        resp = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "stored"})
    assert resp.status_code == 201, resp.text
    return resp.json()
