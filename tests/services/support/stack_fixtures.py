"""The service-test stack, registered for every directory by the root conftest (tests/services and
the API fuzz tests use it): an API with the small limits of `SERVICE_ENV`, tenant clients, the
test scene uploaded once, the model profile of the workers, and private stacks for the modules
whose workers must not share queues with the session's (`private_stack.py` says why).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import httpx
import pytest

from tests.integration.fixtures.pytest_fixtures import serve_api
from tests.integration.fixtures.s3_server import S3Server
from tests.integration.fixtures.services import ApiServer, WorkerPool
from tests.services.conftest import SERVICE_ENV, scene_form

from .private_stack import PrivateStack

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def svc_env(service_env: dict[str, str]) -> dict[str, str]:
    return {**service_env, **SERVICE_ENV}


@pytest.fixture(scope="session")
def api(
    tmp_path_factory: pytest.TempPathFactory, svc_env: dict[str, str], test_api_keys: dict[str, str]
) -> Iterator[ApiServer]:
    """The session's API with the service tests' limits (`api_server` has the defaults)."""
    yield from serve_api(tmp_path_factory.mktemp("svc-api"), svc_env, test_api_keys)


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
    # Imported here: the scene factory renders with torch, and this module is loaded by every
    # pytest run (root conftest), most of which never ask for this scene.
    from .scene_factory import make_scene

    return make_scene(tmp_path_factory.mktemp("scene") / "blobs")


@pytest.fixture(scope="session")
def stored_scene(api: ApiServer, scene_dir: Path) -> dict:
    """A scene of tenant-a uploaded once per session (the 'earlier data' bad uploads must not touch)."""
    with api.client("tenant-a") as client:
        resp = client.post("/v1/scenes", files=scene_form(scene_dir), data={"name": "stored"})
    assert resp.status_code == 201, resp.text
    return resp.json()


@pytest.fixture(scope="session")
def model_profile(tmp_path_factory: pytest.TempPathFactory) -> str | None:
    """None (the bundled default profile) when the repository's tiny CLIP exists, else a profile
    around a random tiny CLIP made for this session."""
    if (REPO / "bayesian_fields_core" / "models" / "tiny-clip" / "config.json").is_file():
        return None
    from tests.core.perception.conftest import make_tiny_clip

    folder = tmp_path_factory.mktemp("profile")
    clip = make_tiny_clip(folder / "tiny-clip")
    profile = folder / "profile.yaml"
    profile.write_text(
        "name: service-test\n"
        "segmenter: {kind: classical, params: {method: felzenszwalb, scale: 300, sigma: 0.8, min_size: 50, min_area: 16}}\n"
        f"encoder: {{kind: hf_clip, path: {clip}, device: cpu}}\n"
        "calibration: {mu0: -0.05, mu1: 0.05, s: 0.1}\n"  # random CLIP: cosines near 0
    )
    return str(profile)


@pytest.fixture(scope="session")
def worker_env(model_profile: str | None) -> dict[str, str]:
    return {"BFIELDS_MODEL_PROFILE": model_profile} if model_profile else {}


@pytest.fixture(scope="module")
def workers(celery_workers: WorkerPool, worker_env: dict[str, str]) -> Iterator[WorkerPool]:
    """One worker per queue (solo pool) with the service test settings."""
    env = {**SERVICE_ENV, **worker_env}
    started = [celery_workers.start("gpu", extra_env=env), celery_workers.start("cpu", extra_env=env)]
    yield celery_workers
    for worker in started:
        if worker.alive:
            worker.stop()


@pytest.fixture(scope="module")
def private_stacks(
    tmp_path_factory: pytest.TempPathFactory,
    s3_server: S3Server,
    test_api_keys: dict[str, str],
    worker_env: dict[str, str],
) -> Iterator[Callable[[str, Mapping[str, str]], PrivateStack]]:
    """`make(name, extra_env)`: a not yet started `PrivateStack` of this module's own, on the
    session's S3 server and keys, its workers with the model profile; all stopped after the module."""
    made: list[PrivateStack] = []

    def make(name: str, extra_env: Mapping[str, str]) -> PrivateStack:
        env = {**worker_env, **extra_env}
        stack = PrivateStack(tmp_path_factory.mktemp(name), s3_server.env(), dict(test_api_keys), env)
        made.append(stack)
        return stack

    yield make
    for stack in reversed(made):
        stack.stop()
