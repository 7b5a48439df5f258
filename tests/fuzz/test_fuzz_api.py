"""Fuzz the API's upload and job routes over real HTTP (uvicorn + rclone S3 + Redis, the
service fixtures): the property is "a 4xx naming the problem, or success; never a 5xx; nothing
stored changed" (the session's stored scene is byte-identical after every case, and a refused
upload adds no scene). Fewer cases than the library fuzz: each is a real request.

Task strings exclude lone UTF-16 surrogates here: refusing those at the edge is issue 12 item 1,
fixed on another branch; add "Cs" back to the alphabet once it is merged.
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from . import strategies as fz
from .conftest import budget, count

pytestmark = [pytest.mark.integration, pytest.mark.fuzz]

CAMERA_NAMES = st.sampled_from(
    ["transforms.json", "cameras.json", "cameras.txt", "images.txt", "cameras.bin", "images.bin", "x.json"]
)


def _scene_ids(client: httpx.Client) -> set[str]:
    resp = client.get("/v1/scenes", params={"limit": 500})
    assert resp.status_code == 200, resp.text
    return {s["id"] for s in resp.json()["items"]}


@st.composite
def upload_forms(draw, folder: Path) -> list:
    """A multipart form whose splat, cameras or images (one of them, or several) are fuzzed."""
    images = [("images", (p.name, p.read_bytes())) for p in sorted((folder / "images").iterdir())]
    splat = ("splat", ("splat.ply", (folder / "splat.ply").read_bytes()))
    cameras = [("cameras", ("transforms.json", (folder / "transforms.json").read_bytes()))]
    target = draw(st.sampled_from(["splat", "cameras", "colmap", "images", "all"]))
    if target in ("splat", "all"):
        splat = ("splat", (draw(st.sampled_from(["splat.ply", "s.PLY", "s.txt"])), draw(fz.ply_files())))
    if target in ("cameras", "all"):
        doc = draw(st.one_of(fz.transforms_docs(), fz.cameras_json_docs()))
        cameras = [("cameras", (draw(CAMERA_NAMES), doc))]
    if target == "colmap":
        cams, imgs = draw(st.one_of(fz.colmap_text_models(), fz.colmap_binary_models()))
        ext = draw(st.sampled_from([".txt", ".bin"]))
        cameras = [("cameras", (f"cameras{ext}", cams)), ("cameras", (f"images{ext}", imgs))]
    if target in ("images", "all"):
        kind = draw(st.sampled_from(["zip", "tar"]))
        blob = draw(fz.zip_archives() if kind == "zip" else fz.tar_archives())
        images = [("images", (f"images.{kind}", blob))]
    return [splat, *cameras, *images]


def test_fuzz_upload_route(api, scene_dir: Path, stored_scene: dict) -> None:
    """POST /v1/scenes with fuzzed parts."""

    @budget(200)
    @given(form=upload_forms(scene_dir))
    def run(form: list) -> None:
        count("api: POST /v1/scenes (fuzzed splat / cameras / archive)")
        with api.client("tenant-a") as client:
            before = _scene_ids(client)
            resp = client.post("/v1/scenes", files=form)
            assert resp.status_code < 500, (resp.status_code, resp.text)
            if resp.status_code == 201:
                created = resp.json()["id"]
                assert _scene_ids(client) == before | {created}
                assert client.delete(f"/v1/scenes/{created}").status_code == 204
            else:
                assert resp.status_code in (413, 415, 422), resp.text
                detail = resp.json()["detail"]
                assert isinstance(detail, str) and detail and "/tmp" not in detail
                assert _scene_ids(client) == before
            assert client.get(f"/v1/scenes/{stored_scene['id']}").json() == stored_scene

    run()


TASK_TEXTS = st.text(st.characters(blacklist_categories=("Cs",)), max_size=70)


def test_fuzz_job_route(api, stored_scene: dict) -> None:
    """POST /v1/jobs with fuzzed task lists and parameters; accepted jobs are cancelled at once."""

    @budget(100)
    @given(
        tasks=st.one_of(st.lists(TASK_TEXTS, max_size=25), fz.json_values),
        params=st.one_of(
            st.just({}),
            st.dictionaries(st.sampled_from(["top_k", "stride", "bogus"]), fz.json_values, max_size=2),
        ),
    )
    def run(tasks: object, params: object) -> None:
        count("api: POST /v1/jobs (fuzzed tasks / parameters)")
        try:  # NaN / Infinity in parameters are issue 12 item 4 (another branch); JSON proper here
            body = json.dumps(
                {"scene_id": stored_scene["id"], "tasks": tasks, "parameters": params}, allow_nan=False
            )
        except ValueError:
            assume(False)
        with api.client("tenant-a") as client:
            resp = client.post("/v1/jobs", content=body, headers={"content-type": "application/json"})
            assert resp.status_code < 500, (resp.status_code, resp.text)
            if resp.status_code == 202:
                job_id = resp.json()["id"]
                assert client.delete(f"/v1/jobs/{job_id}").status_code == 202
                assert client.get(f"/v1/jobs/{job_id}").status_code == 200
            else:
                assert resp.status_code in (400, 422, 429), resp.text
            assert client.get(f"/v1/scenes/{stored_scene['id']}").json() == stored_scene

    run()
