"""Issue 42's "done when": the sample scene submitted as a batch through the real stack (API,
control process, Celery workers on both queues, S3, PostgreSQL) gives a batch answer table whose
first answer per task equals `bfields run samples/tabletop`'s, for every task and every job; a
second tenant sees none of it.

The issue's 20 jobs: perceive runs once (its frames cached for the other 19), fuse and cluster
on the sample's 8 tasks for each, in one single-threaded worker per queue. Measured on the shared
2-core machine: the 20 jobs in 104 s and the module in 158 s (the CLI's reference run and the
stack's start included) at a load average of 6-8 from other work; the jobs in 40 s and the
module's setup in 55 s at a load of about 2. Both runs use
`max_frames` 4 (the CLI with `--param max_frames=4`): the comparison needs the same parameters,
and 4 frames keep a job short (the CLI's default, every one of the sample's 20 frames, took 85 s
for one run here).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
import yaml

from tests.integration.fixtures.services import ApiServer, WorkerPool
from tests.services.conftest import scene_form

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(900)]

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "samples" / "tabletop"
TASKS = [str(t["task"]) for t in yaml.safe_load((SAMPLE / "tasks.yaml").read_text())["tasks"]]
PARAMS = {"max_frames": 4}
JOBS = 20


@pytest.fixture(scope="module")
def cli_summary(tmp_path_factory: pytest.TempPathFactory, model_profile: str | None) -> dict:
    """`bfields run samples/tabletop` as a user runs it, single-threaded like the workers (the same
    float sums), with the test's parameters; its result's summary."""
    out = tmp_path_factory.mktemp("cli") / "run"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "bayesian_fields_core.cli", "run", str(SAMPLE), "--out", str(out), "-q",
           *(a for k, v in PARAMS.items() for a in ("--param", f"{k}={v}"))]  # fmt: skip
    if model_profile:
        cmd += ["--profile", model_profile]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads((out / "result" / "summary.json").read_text())


@pytest.fixture(scope="module")
def sample_batch(
    api_server: ApiServer, workers: WorkerPool, tmp_path_factory: pytest.TempPathFactory
) -> dict:
    """The sample uploaded once by tenant-a (the API with the default upload limits: the sample is
    2.7 MB) and `JOBS` jobs of it with its own task list, as one batch, all succeeded."""
    folder = tmp_path_factory.mktemp("sample") / "tabletop"
    shutil.copytree(SAMPLE, folder)
    (folder / "splat.ply").symlink_to(folder / "point_cloud.ply")  # the name `scene_form` sends
    with httpx.Client(
        base_url=api_server.base_url, headers=api_server.headers("tenant-a"), timeout=120
    ) as client:
        resp = client.post("/v1/scenes", files=scene_form(folder), data={"name": "tabletop"})
        assert resp.status_code == 201, resp.text
        scene_id = resp.json()["id"]
        items = [{"scene_id": scene_id, "tasks": TASKS} for _ in range(JOBS)]
        resp = client.post("/v1/batches", json={"items": items, "parameters": PARAMS})
        assert resp.status_code == 202, resp.text
        batch = resp.json()
        t0 = time.monotonic()
        deadline = t0 + 780
        while not (got := client.get(f"/v1/batches/{batch['id']}").json())["finished"]:
            assert time.monotonic() < deadline, got
            time.sleep(1)
        assert got["counts"] == {"succeeded": JOBS}, got
        jobs = client.get(f"/v1/batches/{batch['id']}/jobs", params={"limit": 500}).json()["items"]
    print(f"{JOBS} sample jobs in {time.monotonic() - t0:.0f} s")
    return {"id": batch["id"], "scene_id": scene_id, "jobs": [j["id"] for j in jobs]}


def _table(client: httpx.Client, batch_id: str) -> list[dict]:
    rows, cursor = [], None
    while True:
        page = client.get(
            f"/v1/batches/{batch_id}/answers", params={"limit": 500, **({"cursor": cursor} if cursor else {})}
        )
        assert page.status_code == 200, page.text
        rows += page.json()["items"]
        if not (cursor := page.json()["next_cursor"]):
            return rows


def test_each_jobs_first_answer_per_task_is_the_clis(
    sample_batch: dict, cli_summary: dict, api_server: ApiServer
) -> None:
    assert cli_summary["tasks"] == TASKS
    expected = {}
    for entry in cli_summary["selections"]:
        objects = entry["objects"]
        expected[entry["task"]] = (
            (True, objects[0]["object_id"], objects[0]["key"], objects[0]["probability"])
            if objects
            else (False,)
        )
    assert set(expected) == set(TASKS) and any(e[0] for e in expected.values())
    with api_server.client("tenant-a") as client:
        rows = _table(client, sample_batch["id"])
    assert {r["job_id"] for r in rows} == set(sample_batch["jobs"]) and len(sample_batch["jobs"]) == JOBS
    for job_id in sample_batch["jobs"]:
        firsts = {r["task"]: r for r in rows if r["job_id"] == job_id and r["rank"] in (0, 1)}
        assert sorted(firsts) == sorted(TASKS), job_id
        for task, want in expected.items():
            got = firsts[task]
            assert got["scene_id"] == sample_batch["scene_id"] and got["scene_name"] == "tabletop"
            if not want[0]:
                assert (got["found"], got["rank"], got["object_id"]) == (False, 0, None), (job_id, task, got)
                continue
            assert (got["found"], got["rank"], got["object_id"], got["content_key"]) == (True, 1, *want[1:3]), (
                job_id, task, got, want,
            )  # fmt: skip
            # two processes' float32 sums may differ in the last bits (tests/services/stack/test_workers.py)
            assert got["probability"] == pytest.approx(want[3], rel=1e-5, abs=1e-7), (job_id, task)


def test_a_second_tenant_sees_none_of_it(sample_batch: dict, api_server: ApiServer) -> None:
    with api_server.client("tenant-b") as other:
        for params in ({}, {"format": "csv"}, {"format": "jsonl"}, {"task": TASKS[0]}):
            got = other.get(f"/v1/batches/{sample_batch['id']}/answers", params=params)
            assert got.status_code == 404, (params, got.text)
        for task in TASKS:
            fleet = other.get("/v1/answers", params={"task": task})
            assert fleet.status_code == 200, fleet.text
            assert (fleet.json()["asked"], fleet.json()["items"]) == (0, [])
        scoped = other.get("/v1/answers", params={"task": TASKS[0], "batch": sample_batch["id"]})
        assert scoped.status_code == 404
    with api_server.client("tenant-a") as owner:  # the same questions answered for its owner
        fleet = owner.get("/v1/answers", params={"task": TASKS[0]}).json()
        assert fleet["asked"] >= 1
