"""Job listing filters by state and by scene in the records database (issue 12, item 8; issue 28):
a filtered page holds exactly the matching jobs, newest first, however many other jobs the tenant
has, and its cursor pages on. Real HTTP for behaviour, and the same listing through the
`JobStore` on the stack's own PostgreSQL database."""

from __future__ import annotations

import httpx
import pytest
import redis

from bayesian_fields_service.jobs.model import JobState
from bayesian_fields_service.jobs.store import JobStore
from bayesian_fields_service.records.database import engine
from tests.integration.fixtures.s3_server import S3Server

pytestmark = pytest.mark.integration


def test_filtered_pages_hold_exactly_the_matching_jobs(
    client_a: httpx.Client, stored_scene: dict, s3_server: S3Server, svc_env: dict[str, str]
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

        # pages of 7 of the cancelled ones: every job once, newest first, then no cursor
        jobs = JobStore(
            s3_server.store(), redis.Redis.from_url(svc_env["BFIELDS_REDIS_URL"]),
            engine(svc_env["BFIELDS_DATABASE_URL"]),
        )  # fmt: skip
        seen: list[str] = []
        cursor = None
        while True:
            items, cursor = jobs.list(
                "tenant-a", state=JobState.cancelled, scene_id=sid, limit=7, cursor=cursor
            )
            seen += [r.id for r in items]
            if cursor is None:
                break
        assert seen == sorted(seen, reverse=True) and len(seen) == len(set(seen))
        assert set(others) <= set(seen) and keep not in seen
    finally:
        client_a.delete(f"/v1/jobs/{keep}")


@pytest.mark.parametrize(
    "cursor",
    ["\x13\x00abc", "j_" + "0" * 21 + "\x00", "j_zz", "' OR 1=1 --", "j_" + "a" * 40],
)
def test_a_cursor_the_route_never_returned_is_a_422(client_a: httpx.Client, cursor: str) -> None:
    """schemathesis sent a cursor holding a NUL byte, which PostgreSQL refuses in text (500)."""
    answer = client_a.get("/v1/jobs", params={"cursor": cursor, "limit": 3})
    assert answer.status_code == 422, answer.text
    assert "cursor" in answer.text
