"""Every query value that reaches the records is checked at the edge (issue 41, item 6): cursors
are ids or positions of ASCII digits within the column's range, usage days fall within a year
range, filters are ids, no value holds a NUL; anything else is a 422 naming the parameter, never a
500 (a position past a bigint, a day past 9999) nor a 200 with an empty page (a scene filter
that could never match). Real HTTP against the service tests' API and its PostgreSQL."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.integration

MAX_POSITION = 2**31 - 1 - 501  # services/api/query.py: position + a page within an `integer`


@pytest.fixture(scope="module")
def batch_id(api, stored_scene: dict) -> Iterator[str]:  # noqa: ANN001
    """A real batch of tenant-a with two jobs (cancelled after the module)."""
    with api.client("tenant-a") as client:
        made = client.post(
            "/v1/batches", json={"scene_ids": [stored_scene["id"]], "task_lists": [["a"], ["b"]]}
        )
        assert made.status_code == 202, made.text
        yield made.json()["id"]
        client.post(f"/v1/batches/{made.json()['id']}/cancel")


def _refused(resp: httpx.Response, field: str) -> None:
    """A 422 `Problem` whose detail and errors name `query.<field>`."""
    assert resp.status_code == 422, (field, resp.status_code, resp.text)
    body = resp.json()
    assert f"query.{field}" in body["detail"], body
    assert any(e["loc"] == ["query", field] for e in body["errors"]), body


HOSTILE_POSITIONS = [
    "9223372036854775807", str(2**63), str(2**64), "1" * 19, "1" * 20, str(MAX_POSITION + 1),
    "\u00b2", "\u0661\u0662", "\uff11\uff12", "-1", "+1", " 1", "1 ", "1.0", "0x10", "1e3", "1_0",
    "\x00", "1\x00", "", "1\n",
]  # fmt: skip


@pytest.mark.parametrize("cursor", HOSTILE_POSITIONS)
def test_a_batch_cursor_that_is_not_a_position_is_a_422(
    client_a: httpx.Client, batch_id: str, cursor: str
) -> None:
    """It was a 500 past a bigint (NumericValueOutOfRange) and for '²' (isdigit, not int)."""
    _refused(client_a.get(f"/v1/batches/{batch_id}/jobs", params={"cursor": cursor}), "cursor")


def test_positions_within_the_range_page_as_before(client_a: httpx.Client, batch_id: str) -> None:
    first = client_a.get(f"/v1/batches/{batch_id}/jobs", params={"limit": 1}).json()
    assert len(first["items"]) == 1 and first["next_cursor"] == "1"
    second = client_a.get(f"/v1/batches/{batch_id}/jobs", params={"limit": 1, "cursor": "1"}).json()
    assert len(second["items"]) == 1 and second["items"][0]["id"] != first["items"][0]["id"]
    last = client_a.get(f"/v1/batches/{batch_id}/jobs", params={"cursor": str(MAX_POSITION), "limit": 500})
    assert last.status_code == 200 and last.json() == {"items": [], "next_cursor": None}


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cursor=st.text(max_size=24))
def test_any_batch_cursor_is_a_page_or_a_422_naming_it(
    client_a: httpx.Client, batch_id: str, cursor: str
) -> None:
    resp = client_a.get(f"/v1/batches/{batch_id}/jobs", params={"cursor": cursor})
    position = cursor.isascii() and cursor.isdigit() and len(cursor) <= 10 and int(cursor) <= MAX_POSITION
    if position:
        assert resp.status_code == 200, (cursor, resp.text)
    else:
        _refused(resp, "cursor")


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("to", "9999-12-31"), ("from", "9999-12-01"), ("to", "0001-01-01"), ("from", "1999-12-31"),
        ("to", "3000-01-01"), ("to", "2024-13-01"), ("to", "2024-02-30"), ("to", "\u0662\u0660\u0662\u0664-01-01"),
        ("from", "\x00"), ("to", "2024-01-01\x00"), ("to", "99999999999999999999"), ("from", "-1"),
    ],
)  # fmt: skip
def test_a_usage_day_outside_the_years_is_a_422(client_a: httpx.Client, field: str, value: str) -> None:
    """`to=9999-12-31` was a 500 (the day after it is past Python's dates)."""
    _refused(client_a.get("/v1/usage", params={field: value}), field)


def test_usage_at_the_edges_of_the_years_answers(client_a: httpx.Client) -> None:
    last = client_a.get("/v1/usage", params={"to": "2999-12-31"})
    assert last.status_code == 200 and last.json()["from"] == "2999-12-01", last.text
    first = client_a.get("/v1/usage", params={"from": "2000-01-01", "to": "2000-01-31"})
    assert first.status_code == 200, first.text


@pytest.mark.parametrize(
    ("path", "field", "value"),
    [
        ("/v1/jobs", "scene_id", "\x00"),
        ("/v1/jobs", "scene_id", "s_" + "0" * 21 + "\x00"),
        ("/v1/jobs", "scene_id", "s_" + "0" * 10_000),
        ("/v1/jobs", "scene_id", "-1"),
        ("/v1/jobs", "scene_id", "s_" + "F" * 22),
        ("/v1/jobs", "scene_id", "s_0192f3a1b2c3aa55bb66cc\n"),
        ("/v1/jobs", "scene_id", "j_0192f3a1b2c3aa55bb66cc"),
        ("/v1/jobs", "scene_id", ""),
        ("/v1/jobs", "cursor", "\u0661\u0662\u0663"),
        ("/v1/jobs", "cursor", "\uff11\uff12\uff13"),
        ("/v1/jobs", "cursor", "j_" + "\u0660" * 22),
        ("/v1/jobs", "limit", "\u0665"),
        ("/v1/jobs", "limit", "9" * 30),
        ("/v1/jobs", "limit", "-1"),
        ("/v1/jobs", "state", "\x00"),
        ("/v1/jobs", "state", "nope"),
        ("/v1/scenes", "cursor", "\uff53_" + "0" * 22),
        ("/v1/scenes", "cursor", "s_" + "\u0660" * 22),
        ("/v1/scenes", "limit", "\u0661\u0660"),
    ],
)
def test_filters_cursors_and_limits_that_no_route_issues_are_a_422(
    client_a: httpx.Client, path: str, field: str, value: str
) -> None:
    """A NUL, huge or negative scene filter, and cursors in other scripts' digits, were a 200 with
    an empty list: a client's mistake hidden as 'nothing there'."""
    _refused(client_a.get(path, params={field: value}), field)


def test_a_nul_in_any_query_value_is_a_422_naming_it(client_a: httpx.Client, batch_id: str) -> None:
    _refused(client_a.get(f"/v1/batches/{batch_id}", params={"jobs": "true\x00"}), "jobs")
    _refused(client_a.get("/v1/jobs", params={"unknown": "\x00"}), "unknown")


def test_a_scene_filter_of_an_id_that_does_not_exist_is_an_empty_page(client_a: httpx.Client) -> None:
    resp = client_a.get("/v1/jobs", params={"scene_id": "s_" + "f" * 22})
    assert resp.status_code == 200 and resp.json()["items"] == []
