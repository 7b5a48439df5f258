"""Result format: round trips through a LocalStore, id encodings, version and integrity checks,
and the .ply exports read back with the scene reader."""

from __future__ import annotations

import json
import zlib

import jsonschema
import numpy as np
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.obb import minimum_obb
from bayesian_fields_core.geometry.spherical_harmonics import SH_C0
from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.objects.not_found import not_found_reason
from bayesian_fields_core.results import (
    FORMAT_VERSION,
    NotFound,
    Result,
    SelectedObject,
    read_result,
    result_sizes,
    write_result,
)
from bayesian_fields_core.results.colours import BACKGROUND_GREY, object_palette
from bayesian_fields_core.results.format import (
    compress,
    decode_ids,
    decompress,
    encode_ids,
    id_dtype,
)
from bayesian_fields_core.results.summary_schema import summary_schema
from bayesian_fields_core.scene.ply import read_ply
from bayesian_fields_core.scene.similarity import Similarity
from bayesian_fields_core.scene.types import Gaussians

N, NUM_OBJECTS, TASKS = 2000, 6, ["get dish soap", "move hats and gloves"]


def make_gaussians(rng, n=N):
    return Gaussians(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.normal(-4, 0.5, size=(n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(size=(n, 4, 3)).astype(np.float32),
        extra={"nx": np.zeros(n, np.float32), "ny": np.zeros(n, np.float32), "nz": np.ones(n, np.float32)},
    )


def make_result(rng, gaussians):
    ids = rng.integers(-1, NUM_OBJECTS, size=N)
    probs = rng.dirichlet(np.ones(len(TASKS) + 1), size=NUM_OBJECTS).astype(np.float32)

    def selected(task_col, k):
        out = []
        for oid in np.argsort(-probs[:, task_col])[:k]:
            pts = gaussians.means[ids == oid]
            out.append(
                SelectedObject(int(oid), float(probs[oid, task_col]), len(pts), pts.mean(0), minimum_obb(pts))
            )
        return out

    return Result(
        tasks=TASKS,
        object_ids=ids,
        probabilities=probs,
        selections={TASKS[0]: selected(0, 2), TASKS[1]: selected(1, 1)},
        primitive_ids=rng.integers(-1, 300, size=N),
        parameters={"delta": 1e-5, "prior": 0.05},
        models={"clip": "tiny-clip"},
        timings_s={"perceive": 1.5, "fuse": 2.0, "cluster": 0.25},
    )


@pytest.fixture
def setup(tmp_path):
    rng = np.random.default_rng(0)
    g = make_gaussians(rng)
    return LocalStore(tmp_path / "store"), g, make_result(rng, g)


def test_round_trip(setup):
    store, g, res = setup
    written = write_result(store, "jobs/j1/result", res, gaussians=g)
    back = read_result(store, "jobs/j1/result/")
    np.testing.assert_array_equal(back.object_ids, res.object_ids)
    np.testing.assert_array_equal(back.primitive_ids, res.primitive_ids)
    np.testing.assert_array_equal(back.probabilities, res.probabilities)
    assert back.tasks == TASKS
    assert back.parameters == res.parameters and back.models == res.models
    assert back.timings_s == res.timings_s
    for task in TASKS:
        for a, b in zip(back.selections[task], res.selections[task], strict=True):
            assert (a.object_id, a.num_gaussians) == (b.object_id, b.num_gaussians)
            assert a.probability == pytest.approx(b.probability)
            np.testing.assert_allclose(a.box.rotation, b.box.rotation)
            assert a.export == f"exports/objects/object_{a.object_id:05d}.ply"
    summary = json.loads(store.get_bytes("jobs/j1/result/summary.json"))
    assert summary["arrays"]["object_ids"]["dtype"] == "|u1"
    assert summary["arrays"]["object_ids"]["sentinel"] == 255
    assert summary["arrays"]["primitive_ids"]["dtype"] == "<u2"  # ids up to 299
    assert summary["counts"] == {
        "gaussians": N,
        "gaussians_in_objects": int((res.object_ids >= 0).sum()),
        "primitives": len(np.unique(res.primitive_ids[res.primitive_ids >= 0])),
        "objects": NUM_OBJECTS,
        "tasks": 2,
        "selected_objects": 3,
    }
    assert [s["task"] for s in summary["selections"]] == TASKS
    sizes = result_sizes(store, "jobs/j1/result")
    assert {k: v for k, v in sizes.items() if not k.startswith("total/")} == written
    assert sizes["total/object_map"] == sum(
        written[k] for k in ("summary.json", "object_ids.bin", "probabilities.bin")
    )
    assert sizes["total/with_primitives"] == sizes["total/object_map"] + written["primitive_ids.bin"]
    assert sizes["total/exports"] == sum(v for k, v in written.items() if k.startswith("exports/")) > 0


def test_exports_open_as_splats(setup, tmp_path):
    store, g, res = setup
    write_result(store, "r", res, gaussians=g)
    oid = res.selections[TASKS[0]][0].object_id
    store.get_file(f"r/exports/objects/object_{oid:05d}.ply", tmp_path / "obj.ply")
    obj = read_ply(tmp_path / "obj.ply")
    mask = res.object_ids == oid
    np.testing.assert_array_equal(obj.means, g.means[mask])
    np.testing.assert_array_equal(obj.sh, g.sh[mask])  # all attributes untouched
    np.testing.assert_array_equal(obj.quats, g.quats[mask])
    store.get_file("r/exports/scene_objects.ply", tmp_path / "scene.ply")
    scene = read_ply(tmp_path / "scene.ply")
    assert len(scene) == N
    assert not scene.sh[:, 1:, :].any()
    rgb = 0.5 + SH_C0 * scene.sh[:, 0, :]
    none = res.object_ids < 0
    np.testing.assert_allclose(rgb[none], BACKGROUND_GREY, atol=1e-6)
    np.testing.assert_allclose(
        rgb[res.object_ids == 3],
        np.broadcast_to(object_palette(NUM_OBJECTS)[3], rgb[res.object_ids == 3].shape),
        atol=1e-6,
    )
    assert len(np.unique(np.round(object_palette(NUM_OBJECTS), 3), axis=0)) == NUM_OBJECTS
    # rewriting without a splat removes the stale exports
    write_result(store, "r", res)
    assert not store.list("r/exports/")
    assert all(o.export is None for o in read_result(store, "r").selections[TASKS[0]])


def test_id_encoding_by_hand():
    assert id_dtype(0) == np.dtype("u1") and id_dtype(254) == np.dtype("u1")
    assert id_dtype(255) == np.dtype("<u2") and id_dtype(65534) == np.dtype("<u2")
    assert id_dtype(65535) == np.dtype("<u4")
    stored, sentinel = encode_ids(np.array([-1, 0, 254, 7]))
    assert sentinel == 255 and stored.dtype == np.uint8
    np.testing.assert_array_equal(stored, [255, 0, 254, 7])
    np.testing.assert_array_equal(decode_ids(stored, sentinel), [-1, 0, 254, 7])
    stored, sentinel = encode_ids(np.array([-1, 255]))
    assert sentinel == 65535 and stored.tolist() == [65535, 255]


def test_codec_choice():
    codec, data = compress(bytes(100_000))
    assert codec in ("zlib", "lzma") and len(data) < 1000
    assert decompress(codec, data, expected=100_000, name="x") == bytes(100_000)
    assert compress(b"\x01\x02")[0] == "raw"
    with pytest.raises(InputError, match="expected 10 bytes"):
        decompress("zlib", zlib.compress(bytes(100)), expected=10, name="x")


def test_version_and_integrity_checks(setup):
    store, _, res = setup
    write_result(store, "r", res)
    summary = json.loads(store.get_bytes("r/summary.json"))
    summary["format_version"] = "1.7"  # a later minor stays readable
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    read_result(store, "r")
    summary["format_version"] = "2.0"
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    with pytest.raises(InputError, match="format version '2.0'"):
        read_result(store, "r")
    write_result(store, "r", res)
    ids = res.object_ids.copy()
    ids[0] = (ids[0] + 1) % NUM_OBJECTS
    store.put_bytes("r/object_ids.bin", zlib.compress(encode_ids(ids)[0].tobytes()))
    summary = json.loads(store.get_bytes("r/summary.json"))
    summary["arrays"]["object_ids"]["codec"] = "zlib"
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    with pytest.raises(InputError, match="checksum"):
        read_result(store, "r")
    with pytest.raises(InputError, match="no result"):
        read_result(store, "elsewhere")


def test_invalid_results_are_refused(setup):
    store, g, res = setup
    res.probabilities = res.probabilities[:, :2]
    with pytest.raises(InputError, match="probabilities"):
        write_result(store, "r", res)
    rng = np.random.default_rng(1)
    good = make_result(rng, g)
    good.object_ids = good.object_ids.copy()
    good.object_ids[0] = NUM_OBJECTS
    with pytest.raises(InputError, match="object_ids"):
        write_result(store, "r", good)
    with pytest.raises(InputError, match="Gaussians"):
        write_result(store, "r", make_result(rng, g), gaussians=g.subset(np.arange(10)))


def test_relevance_round_trip_and_optional(setup):
    """Format 1.1's relevance table comes back exactly; a result without it still reads (1.0)."""
    store, _, res = setup
    res.relevance = np.random.default_rng(3).random((NUM_OBJECTS, len(TASKS))).astype(np.float32)
    written = write_result(store, "r", res)
    back = read_result(store, "r")
    np.testing.assert_array_equal(back.relevance, res.relevance)
    assert back.format_version == FORMAT_VERSION == "1.6"
    assert result_sizes(store, "r")["total/object_map"] == sum(
        written[k] for k in ("summary.json", "object_ids.bin", "probabilities.bin", "relevance.bin")
    )
    res.relevance = None
    write_result(store, "r", res)
    assert read_result(store, "r").relevance is None
    assert not store.exists("r/relevance.bin")  # no stale table from the earlier write
    res.relevance = np.zeros((NUM_OBJECTS, len(TASKS) + 1), dtype=np.float32)
    with pytest.raises(InputError, match="relevance"):
        write_result(store, "r", res)


def test_not_found_task_round_trips_with_an_empty_selection_and_its_reason(setup):
    """Format 1.3: a task left unanswered by the "not found" rule keeps its reason; 1.2 results
    (no such field) read with none; a task both answered and "not found" is refused."""
    store, g, res = setup
    missing = NotFound(
        reason="best object 3 has relevance 0.210 < 0.5",
        rule="relevance",
        threshold=0.5,
        score=0.21,
        object_id=3,
    )
    res.selections[TASKS[1]] = []
    res.not_found = {TASKS[1]: missing}
    write_result(store, "r", res, gaussians=g)
    summary = json.loads(store.get_bytes("r/summary.json"))
    entry = summary["selections"][1]
    assert entry == {"task": TASKS[1], "objects": [], "not_found": missing.to_dict()}
    assert "not_found" not in summary["selections"][0]
    back = read_result(store, "r")
    assert back.selections[TASKS[1]] == [] and back.not_found == {TASKS[1]: missing}
    assert back.selections[TASKS[0]] and TASKS[0] not in back.not_found
    # No export for a task without objects beyond the (grey) task splat.
    assert set(summary["exports"]["objects"]) == {str(o.object_id) for o in res.selections[TASKS[0]]}
    # A 1.2 summary has no not_found entries.
    del summary["selections"][1]["not_found"]
    summary["format_version"] = "1.2"
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    assert read_result(store, "r").not_found == {}
    # Malformed or contradictory entries are refused.
    summary["selections"][1]["not_found"] = {"rule": "relevance", "threshold": 0.5}
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    with pytest.raises(InputError, match="not_found missing field 'reason'"):
        read_result(store, "r")
    res.not_found = {TASKS[0]: missing}
    with pytest.raises(InputError, match="both answered and not found"):
        write_result(store, "r", res)


def _with_world_frame(res: Result) -> Result:
    """`res` as a run on a nerfstudio capture reports it (format 1.4): each answer with its ranking
    score and its world-frame copy, the capture-to-world transform, the scene scale."""
    to_world = Similarity(1.0, np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), np.array([0.5, 0, 0]))
    for objs in res.selections.values():
        for rank, obj in enumerate(objs):
            obj.score = 10.0 - rank
            obj.world_centroid = to_world.points(obj.centroid)
            obj.world_box = to_world.box(obj.box)
    res.capture_to_world = to_world.matrix
    res.scene_scale = {
        "value": 1.85,
        "source": "derived",
        "units": "scene units",
        "lengths": {"depth_tolerance": 0.05},
    }
    res.ranked_by = "evidence"
    return res


def test_format_1_4_fields_round_trip_and_name_the_frames(setup):
    store, g, res = setup
    res = _with_world_frame(res)
    write_result(store, "r", res, gaussians=g)
    summary = json.loads(store.get_bytes("r/summary.json"))
    assert summary["format_version"] == FORMAT_VERSION == "1.6"
    assert set(summary["frames"]["names"]) == {"splat", "world"}  # no capture frame: one with the splat
    assert summary["scene_scale"]["value"] == 1.85 and summary["ranked_by"] == "evidence"
    back = read_result(store, "r")
    np.testing.assert_allclose(back.capture_to_world, res.capture_to_world)
    assert back.scene_scale == res.scene_scale and back.ranked_by == "evidence"
    for task in TASKS:
        for a, b in zip(back.selections[task], res.selections[task], strict=True):
            assert a.score == b.score
            np.testing.assert_allclose(a.world_centroid, b.world_centroid)
            np.testing.assert_allclose(a.world_box.center, b.world_box.center)


def test_a_1_3_result_still_reads(setup):
    """A reader of 1.4 reads a 1.3 summary (none of the new fields): they come back empty."""
    store, g, res = setup
    write_result(store, "r", _with_world_frame(res))
    summary = json.loads(store.get_bytes("r/summary.json"))
    summary["format_version"] = "1.3"
    for key in ("scene_scale", "ranked_by"):
        del summary[key]
    del summary["frames"]["capture_to_world"], summary["frames"]["names"]
    for entry in summary["selections"]:
        for obj in entry["objects"]:
            del obj["score"], obj["world_frame"]
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    back = read_result(store, "r")
    assert back.format_version == "1.3" and back.capture_to_world is None and back.scene_scale is None
    assert back.ranked_by == ""
    obj = back.selections[TASKS[0]][0]
    assert obj.score is None and obj.world_centroid is None and obj.world_box is None


def test_the_best_view_score_is_written_under_its_new_name_and_the_old_one(setup):
    """Format 1.6 (issue 45, item 12): `best_view_score` (what the "not found" rule thresholds; a
    margin, not a probability) beside `peak` for 1.3-1.5 readers, and the rule named the same way;
    the summary validates against the repo's schema."""
    store, g, res = setup
    first = res.selections[TASKS[0]][0]
    first.peak = 1.19
    res.selections[TASKS[1]] = []
    res.not_found = {TASKS[1]: not_found_reason(4, 0.632, 0.640806)}
    write_result(store, "r", res, gaussians=g)
    summary = json.loads(store.get_bytes("r/summary.json"))
    obj = summary["selections"][0]["objects"][0]
    assert obj["best_view_score"] == obj["peak"] == pytest.approx(1.19)
    assert "best_view_score" not in summary["selections"][0]["objects"][1]  # none recorded: no key
    nf = summary["selections"][1]["not_found"]
    assert nf["rule"] == "best_view_score" and "peak" not in nf["reason"]
    assert nf["reason"] == (
        "best object 4 scored 0.632, below the not-found threshold 0.641 (its best view's match to "
        "the task: 1 = as well as a typical relevant view, 0 = as a typical irrelevant one)"
    )
    jsonschema.validate(summary, summary_schema())
    back = read_result(store, "r").selections[TASKS[0]][0]
    assert back.peak == back.best_view_score == pytest.approx(1.19)


def test_a_summary_with_only_the_old_peak_key_still_reads(setup):
    """A 1.3-1.5 summary (`peak`, rule "peak", the old reason) reads: the score under both names,
    the rule and reason as today's; the new key wins where both are (a 1.6 summary)."""
    store, g, res = setup
    res.selections[TASKS[0]][0].peak = 0.9
    res.selections[TASKS[1]] = []
    res.not_found = {TASKS[1]: not_found_reason(4, 0.632, 0.640806)}
    write_result(store, "r", res, gaussians=g)
    summary = json.loads(store.get_bytes("r/summary.json"))
    summary["format_version"] = "1.5"
    del summary["selections"][0]["objects"][0]["best_view_score"]
    summary["selections"][1]["not_found"] |= {
        "rule": "peak",
        "reason": "best object 4 has peak 0.632 < 0.640806",
    }
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    jsonschema.validate(summary, summary_schema())
    back = read_result(store, "r")
    assert back.selections[TASKS[0]][0].best_view_score == pytest.approx(0.9)
    assert back.not_found[TASKS[1]] == not_found_reason(4, 0.632, 0.640806)  # rule and wording of today
    summary["selections"][0]["objects"][0] |= {"best_view_score": 0.95, "peak": 0.9}
    store.put_bytes("r/summary.json", json.dumps(summary).encode())
    assert read_result(store, "r").selections[TASKS[0]][0].peak == pytest.approx(0.95)
