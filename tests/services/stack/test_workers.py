"""End to end over HTTP with real Celery workers on both queues: the result equals the in-process
pipeline's; a SIGKILLed worker's job completes on a new worker; a Redis restart loses no job;
cancel stops a job; the CLI client's submit/status/fetch work against the live service."""

from __future__ import annotations

import io
import json
import time
import zipfile
from contextlib import redirect_stdout
from pathlib import Path

import httpx
import numpy as np
import pytest

from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_service.client import BFieldsClient, fetch, status, submit
from tests.integration.fixtures.redis_server import RedisServer
from tests.integration.fixtures.services import ApiServer, WorkerPool, build_service_env
from tests.services.conftest import SERVICE_ENV
from tests.services.support.callback_receivers import Receiver
from tests.services.support.private_stack import wait_job
from tests.support.scene_transforms import copy_scene, move_splat

# Longer than the default timeout (pyproject.toml): jobs wait up to 240 s each, after the in-process reference run.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]

TASKS = ["red blob", "green blob"]
PARAMS = {"max_frames": 4}


def _upload(api: ApiServer, scene_dir: Path) -> str:
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        return client.upload_scene(scene_dir)["id"]


def _wait_for(predicate, timeout_s: float, what: str):  # noqa: ANN001, ANN202
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory, scene_dir: Path, model_profile: str | None):
    """The in-process pipeline's result on the same scene, tasks and parameters."""
    import torch

    torch.set_num_threads(1)  # the workers run single-threaded (OMP_NUM_THREADS=1): same sums
    root = tmp_path_factory.mktemp("reference")
    job = local_job(
        scene_dir, root, root, TASKS, PipelineParams.model_validate(PARAMS), load_models(model_profile),
        job_prefix="job/", cache_prefix="scene/cache/",
    )  # fmt: skip
    run_job(job)
    return read_result(LocalStore(root), "job/result/")


def _assert_same_result(folder: Path, reference) -> None:  # noqa: ANN001
    """The same objects, the same selections, and relevance equal to float32 precision.

    Why not bit-equal probabilities: the worker and this test process are two processes whose
    float32 reductions may be ordered differently (CI saw differences of up to 6e-8 absolute, 3.5e-6 relative, in
    8 of 21 entries after the suite had run in the same process for ten minutes); objects and
    selections must still be identical, and a real difference is orders of magnitude larger.
    """
    got = read_result(LocalStore(folder), "result/")
    assert got.tasks == reference.tasks
    np.testing.assert_array_equal(got.object_ids, reference.object_ids)
    np.testing.assert_allclose(got.probabilities, reference.probabilities, rtol=1e-5, atol=1e-7)
    assert {t: [o.object_id for o in objs] for t, objs in got.selections.items()} == {
        t: [o.object_id for o in objs] for t, objs in reference.selections.items()
    }


def test_end_to_end_over_http_matches_in_process(
    api: ApiServer, workers: WorkerPool, scene_dir: Path, reference, tmp_path: Path, client_a: httpx.Client
) -> None:
    scene_id = _upload(api, scene_dir)
    resp = client_a.post("/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS})
    assert resp.status_code == 202, resp.text
    job = wait_job(client_a, resp.json()["id"])
    assert job["state"] == "succeeded", job
    assert job["stages_done"] == ["perceive", "fuse", "cluster"] and job["progress"] == 100.0
    assert set(job["timings"]) == {"perceive", "fuse", "cluster"}
    result = client_a.get(f"/v1/jobs/{job['id']}/result").json()
    assert any(a["path"] == "result/summary.json" for a in result["artifacts"])
    assert result["summary"]["tasks"] == TASKS
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        client.download_artifacts(job["id"], tmp_path / "fetched")
    _assert_same_result(tmp_path / "fetched", reference)
    # "download all": every artifact in one zip, byte for byte what the single downloads give
    archive = client_a.get(f"/v1/jobs/{job['id']}/result.zip")
    assert archive.status_code == 200 and archive.headers["content-type"] == "application/zip"
    with zipfile.ZipFile(io.BytesIO(archive.content)) as zf:
        assert sorted(zf.namelist()) == sorted(a["path"] for a in result["artifacts"])
        for name in zf.namelist():
            assert zf.read(name) == (tmp_path / "fetched" / name).read_bytes(), name
    # tenant-b cannot read the result, one file at a time or all at once
    with api.client("tenant-b") as other:
        assert other.get(f"/v1/jobs/{job['id']}/result").status_code == 404
        assert other.get(f"/v1/jobs/{job['id']}/result.zip").status_code == 404
    # a new task list on the same scene reuses the cached perception (every frame from the cache)
    again = client_a.post("/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS[::-1], "parameters": PARAMS})
    second = wait_job(client_a, again.json()["id"])
    assert second["state"] == "succeeded", second
    assert second["stage_reports"]["perceive"]["frames_cached"] == 4
    metrics = api.metrics()
    assert 'bfields_stage_seconds_count{stage="cluster"}' in metrics
    assert 'bfields_job_seconds_count{outcome="succeeded"}' in metrics
    # each stage's message was stamped where it was sent (the dispatcher: perceive; the previous
    # stage's worker: fuse, cluster) and its wait observed where it started (issue 44)
    for stage in ("perceive", "fuse", "cluster"):
        assert f'bfields_stage_queue_wait_seconds_count{{stage="{stage}"}}' in metrics, stage
        assert f'bfields_stage_gpu_seconds_total{{stage="{stage}"}} 0.0' in metrics, stage  # CPU workers


def test_job_on_a_splat_that_renders_wrong_fails_with_the_reason(
    api: ApiServer, workers: WorkerPool, scene_dir: Path, tmp_path: Path, client_a: httpx.Client
) -> None:
    """Scaled 0.5 and shifted 0.4 m, the splat still sits in front of the cameras (the upload's
    geometric check passes) but its renders do not match the photos: the worker's rendered check
    at the start of perceive fails the job with the one-line reason, as a user error."""
    moved = move_splat(copy_scene(scene_dir, tmp_path / "moved"), scale=0.5, shift=(0.4, 0.0, 0.0))
    scene_id = _upload(api, moved)
    resp = client_a.post("/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS})
    assert resp.status_code == 202, resp.text
    job = wait_job(client_a, resp.json()["id"])
    assert job["state"] == "failed", job
    error = job["error"]
    assert error.startswith("perceive: alignment: renders of the splat do not match the photos"), error
    assert "internal error" not in error and "\n" not in error
    assert "dataparser_transforms.json" in error and "alignment_check=false" in error
    assert job["stages_done"] == []


def test_cli_submit_status_fetch(
    api: ApiServer,
    workers: WorkerPool,
    scene_dir: Path,
    tmp_path: Path,
    reference,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("BFIELDS_API_KEY", api.keys["tenant-a"])
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text("- red blob\n- green blob\n")
    params = tmp_path / "params.yaml"
    params.write_text(json.dumps(PARAMS))
    out = io.StringIO()
    with redirect_stdout(out):
        code = submit(scene_dir, tasks, server=api.base_url, wait=True, parameters=str(params), poll_s=0.5)
    assert code == 0
    job_id = out.getvalue().strip().splitlines()[-1]
    out = io.StringIO()
    with redirect_stdout(out):
        assert status(job_id, server=api.base_url) == 0
    shown = json.loads(out.getvalue())
    assert shown["state"] == "succeeded" and "stage_runs" in shown
    assert "attempts" not in shown  # the API's deprecated former name of stage_runs is not shown
    assert fetch(job_id, tmp_path / "out", server=api.base_url) == 0
    _assert_same_result(tmp_path / "out", reference)


def test_cancel_running_job(
    api: ApiServer, workers: WorkerPool, scene_dir: Path, client_a: httpx.Client
) -> None:
    scene_id = _upload(api, scene_dir)
    # a fresh parameter set (depth source) misses the visibility cache, so fuse has real work to do
    params = {**PARAMS, "depth_source": "expected", "depth_tolerance": 0.0417}
    job_id = client_a.post(
        "/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": params}
    ).json()["id"]
    _wait_for(lambda: client_a.get(f"/v1/jobs/{job_id}").json()["state"] != "queued", 60, "the job to start")
    assert client_a.delete(f"/v1/jobs/{job_id}").status_code == 202
    final = wait_job(client_a, job_id)
    # the cancel lands between frames; a job that finished its last frame first may still succeed
    assert final["state"] in ("cancelled", "succeeded"), final
    if final["state"] == "cancelled":
        assert client_a.get(f"/v1/jobs/{job_id}/result").status_code == 409


def test_worker_sigkilled_mid_job_is_completed_by_a_new_worker(
    api: ApiServer, celery_workers: WorkerPool, worker_env: dict[str, str], scene_dir: Path, tmp_path: Path,
    reference, client_a: httpx.Client, workers: WorkerPool,
) -> None:  # fmt: skip
    env = {**SERVICE_ENV, **worker_env}
    for w in list(celery_workers.workers):
        if w.queue == "gpu" and w.alive:
            w.stop()
    victim = celery_workers.start("gpu", name="victim", extra_env=env)
    scene_id = _upload(api, scene_dir)
    job_id = client_a.post(
        "/v1/jobs", json={"scene_id": scene_id, "tasks": TASKS, "parameters": PARAMS}
    ).json()["id"]
    _wait_for(lambda: client_a.get(f"/v1/jobs/{job_id}").json()["state"] == "running", 120, "the job to run")
    victim.kill()
    assert client_a.get(f"/v1/jobs/{job_id}").json()["state"] == "running"
    celery_workers.start("gpu", name="rescuer", extra_env=env)
    job = wait_job(client_a, job_id)
    assert job["state"] == "succeeded", job
    assert job["attempts"] >= 2  # the killed execution and the rescuing one
    with BFieldsClient(api.base_url, api.keys["tenant-a"]) as client:
        client.download_artifacts(job_id, tmp_path / "fetched")
    _assert_same_result(tmp_path / "fetched", reference)


def test_redis_restart_loses_no_job(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory, s3_server, test_api_keys: dict[str, str],  # noqa: ANN001
    worker_env: dict[str, str], scene_dir: Path,
) -> None:  # fmt: skip
    """A batch (with a callback) queued while no worker runs; Redis restarts WITHOUT persistence
    (queue, live state, everything gone); workers started afterwards recover every job from its
    row, and the batch's callback, decided and queued by the records database, arrives once.
    (Before the transactional outbox, a batch whose jobs finished around a Redis loss never sent
    its callback: its per-job states lived in a Redis hash.)"""
    receiver = Receiver("ok")
    redis_srv = RedisServer(tmp_path / "redis", appendonly=False).start()
    callbacks_on = {"BFIELDS_CALLBACK_SECRET": "test-secret", "BFIELDS_CALLBACK_ALLOW_PRIVATE": "true",
                    "BFIELDS_CALLBACK_POLL_S": "0.2"}  # fmt: skip
    env = build_service_env(
        tmp_path / "env", redis_srv.url(), s3_server.env(), test_api_keys,
        {**SERVICE_ENV, **worker_env, **callbacks_on},
    )  # fmt: skip
    api = ApiServer(env=env, log_dir=tmp_path / "api", keys=dict(test_api_keys)).start()
    pool = WorkerPool(broker_url=redis_srv.url(), env=env, log_dir=tmp_path / "workers")
    try:
        scene_id = _upload(api, scene_dir)
        with api.client("tenant-a") as client:
            batch = client.post("/v1/batches", json={
                "scene_ids": [scene_id], "task_lists": [TASKS, TASKS[::-1]], "parameters": PARAMS,
                "callback_url": receiver.url("/batch"),
            })  # fmt: skip
            assert batch.status_code == 202, batch.text
            ids = [j["id"] for j in batch.json()["jobs"]]
            import redis as redis_lib

            redis_lib.Redis.from_url(redis_srv.url()).set("bf:test:before-the-restart", b"1")
            redis_srv.stop()
            redis_srv.start()
            # everything from before is gone (the API and the control process may write again at
            # once: a key count right after the restart raced with the dispatcher's next send)
            assert redis_lib.Redis.from_url(redis_srv.url()).get("bf:test:before-the-restart") is None
            for job_id in ids:  # the manifests still answer
                assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "queued"
            pool.start("gpu")
            pool.start("cpu")
            finals = [wait_job(client, job_id) for job_id in ids]
        assert [f["state"] for f in finals] == ["succeeded", "succeeded"], finals
        _wait_for(lambda: len(receiver.snapshot()) >= 1, 30, "the batch callback")
        time.sleep(2.0)  # and no second one
        hits = receiver.snapshot()
        assert len(hits) == 1 and hits[0].event_id.startswith(f"batch:{batch.json()['id']}:finished:"), hits
    finally:
        pool.stop_all()
        api.stop()
        redis_srv.stop()
        receiver.close()
