"""Job listing keeps an index per state and per scene (issue 12, item 8): a filtered page reads
only the manifests it returns, however many other jobs the tenant has. Real HTTP for behaviour;
the read count is taken on the real S3 store through a counting view of it."""

from __future__ import annotations

from typing import Any

import httpx
import pytest
import redis

from bayesian_fields_service.common.jobs import JobState, JobStore
from tests.integration.fixtures.s3_server import S3Server

pytestmark = pytest.mark.integration


class CountingStore:
    """The real store, counting the manifests read through it (everything else passes through)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.manifest_reads = 0

    def get_bytes(self, key: str) -> bytes:
        if key.endswith("/manifest.json"):
            self.manifest_reads += 1
        return self.inner.get_bytes(key)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_filtered_page_reads_only_its_own_manifests(
    client_a: httpx.Client, stored_scene: dict, s3_server: S3Server, redis_url: str
) -> None:
    sid = stored_scene["id"]
    keep = client_a.post("/v1/jobs", json={"scene_id": sid, "tasks": ["listed blob"]}).json()["id"]
    others = [
        client_a.post("/v1/jobs", json={"scene_id": sid, "tasks": [f"t{i}"]}).json()["id"] for i in range(30)
    ]
    for job_id in others:
        assert client_a.delete(f"/v1/jobs/{job_id}").json()["state"] == "cancelled"
    try:
        page = client_a.get("/v1/jobs", params={"state": "queued", "scene_id": sid, "limit": 1}).json()
        assert [j["id"] for j in page["items"]] == [keep]
        cancelled = client_a.get(
            "/v1/jobs", params={"state": "cancelled", "scene_id": sid, "limit": 500}
        ).json()
        assert set(others) <= {j["id"] for j in cancelled["items"]} and keep not in {
            j["id"] for j in cancelled["items"]
        }
        assert client_a.get("/v1/jobs", params={"scene_id": "s_" + "f" * 22}).json()["items"] == []

        store = CountingStore(s3_server.store())
        jobs = JobStore(store, redis.Redis.from_url(redis_url))  # type: ignore[arg-type]
        items, _ = jobs.list("tenant-a", state=JobState.queued, scene_id=sid, limit=1)
        assert [r.id for r in items] == [keep]
        assert store.manifest_reads == 1, f"{store.manifest_reads} manifests read for a page of one"
    finally:
        client_a.delete(f"/v1/jobs/{keep}")
