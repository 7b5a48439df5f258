"""Worker disk over real HTTP and real Celery workers (prefork pool on the GPU queue, solo on the
CPU queue, one shared cache folder): N jobs over three scenes leave one scene copy per scene in
the cache, never more than the bound, no partial copies, and nothing in the old per-stage temp
folder. BFIELDS_DISK_JOBS=100 turns it into the disk measurement of the docs (Operations, worker
disk; printed)."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path

import pytest

from tests.services.conftest import SERVICE_ENV
from tests.services.support.private_stack import PrivateStack, upload, wait_job
from tests.services.support.scene_factory import make_scene

pytestmark = [pytest.mark.integration, pytest.mark.slow]

JOBS = int(os.environ.get("BFIELDS_DISK_JOBS", "4"))
PARAMS = {"max_frames": 4}


def _tree_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("disk-scenes")
    return [make_scene(root / f"scene{i}", seed=i) for i in range(3)]


@pytest.fixture(scope="module")
def bound(scenes: list[Path]) -> int:
    """Room for two of the three scenes: the third forces an eviction."""
    return int(2.5 * max(_tree_bytes(s) for s in scenes))


@pytest.fixture(scope="module")
def stack(private_stacks: Callable[[str, Mapping[str, str]], PrivateStack], bound: int) -> PrivateStack:
    stack = private_stacks("disk-stack", {**SERVICE_ENV, "BFIELDS_WORKER_SCENE_CACHE_MAX_BYTES": str(bound)})
    stack.extra_env["BFIELDS_WORKER_SCENE_CACHE_DIR"] = str(stack.tmp / "scene-cache")
    stack.start()
    assert stack.pool is not None
    stack.pool.start("gpu", pool="prefork", concurrency=2)
    stack.pool.start("cpu")
    return stack


def test_one_copy_per_scene_within_the_bound(stack: PrivateStack, scenes: list[Path], bound: int) -> None:
    assert stack.api is not None
    cache = Path(stack.extra_env["BFIELDS_WORKER_SCENE_CACHE_DIR"])
    with stack.api.client("tenant-a") as client:
        ids = [upload(client, s) for s in scenes]
        # scenes 0 and 1 alternate (the cache must serve both from one copy each), then scene 2
        order = [ids[i % 2] for i in range(max(JOBS - 1, 2))] + [ids[2]]
        peak = 0
        for n, scene_id in enumerate(order):
            tasks = ["red blob", "green blob"] if n % 2 == 0 else ["blue blob", "yellow blob"]
            resp = client.post("/v1/jobs", json={"scene_id": scene_id, "tasks": tasks, "parameters": PARAMS})
            assert resp.status_code == 202, resp.text
            job = wait_job(client, resp.json()["id"])
            assert job["state"] == "succeeded", job
            entries = [p for p in cache.iterdir() if not p.name.startswith(".")]
            per_scene = [e.name.split("--")[1] for e in entries]
            assert len(per_scene) == len(set(per_scene)), f"two copies of one scene: {per_scene}"
            used = _tree_bytes(cache)
            peak = max(peak, used)
            assert used <= bound, f"cache holds {used} bytes, bound {bound}"
    names = sorted(e.name.split("--")[1] for e in cache.iterdir() if not e.name.startswith("."))
    # the bound holds two scenes: the least recently used one (scene 0 or 1) was evicted
    assert ids[2] in names and len(names) == 2, names
    assert list((cache / ".partial").iterdir()) == []
    assert not (stack.temp_dir / "bfields-scenes").exists()  # the old per-stage copies
    print(
        f"\nworker disk after {len(order)} jobs on 3 scenes: cache {_tree_bytes(cache)} bytes "
        f"(peak {peak}, bound {bound}, one scene {_tree_bytes(scenes[0])} bytes); "
        f"temp dir {_tree_bytes(stack.temp_dir)} bytes"
    )
