"""The result format: in-memory types, the version policy and the array encodings.

`docs/results-format.md` is the normative description; this module is its executable form.
Arrays are stored as raw little-endian bytes, compressed with whichever of zlib and lzma (both in
the standard library, so any language can read them) gives the smaller file, and described in
`summary.json` (dtype, shape, codec, sentinel, SHA-256 of the raw bytes). Per-Gaussian ids use the
smallest unsigned type that holds the largest id with the type's maximum left free as the "none"
sentinel: the paper stores 8-byte ids (3.04 MB for 400k Gaussians); one byte and a compressor
make the id map one to two orders of magnitude smaller.
"""

from __future__ import annotations

import hashlib
import lzma
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.geometry.box import OrientedBox
from bayesian_fields_core.objects.not_found import NotFound
from bayesian_fields_core.objects.scores import task_scores
from bayesian_fields_core.results.keys import object_keys

FORMAT_NAME = "bayesian-fields-result"
FORMAT_VERSION = "1.6"
"""MAJOR.MINOR. A reader accepts any MINOR of its MAJOR (minors only add optional fields and files);
a new MAJOR (a changed meaning, dtype rule or layout) is refused with a clear error."""

SUMMARY_KEY = "summary.json"
OBJECT_IDS_KEY = "object_ids.bin"
PRIMITIVE_IDS_KEY = "primitive_ids.bin"
PROBABILITIES_KEY = "probabilities.bin"
RELEVANCE_KEY = "relevance.bin"
OBJECT_EXPORT_DIR = "exports/objects/"
SCENE_EXPORT_KEY = "exports/scene_objects.ply"
TASK_EXPORT_DIR = "exports/tasks/"

ID_DTYPES = (np.dtype("<u1"), np.dtype("<u2"), np.dtype("<u4"))
CODECS = ("raw", "zlib", "lzma")
BEST_VIEW_SCORE_KEY = "best_view_score"
"""summary.json key of an object's best-view score (format 1.6; `SelectedObject.peak` in Python)."""
LEGACY_PEAK_KEY = "peak"
"""The same number's key in formats 1.3-1.5. Format 1.6 writes both keys (so 1.3-1.5 readers keep
reading it) and readers take either; the next format version writes only `best_view_score`."""
NULL_TASK = "<null>"
"""Name of the last probability column: relevant to none of the tasks."""


@dataclass
class SelectedObject:
    """One of a task's top-k objects. `num_gaussians`, `centroid` (mean Gaussian centre) and `box`
    describe the object's Gaussians after floater removal, in the frame of the splat file the user
    gave; `export` is the key of its `.ply` (relative to the result prefix) when one was written.
    `capture_centroid` / `capture_box` (format 1.2): the same in the cameras' (capture) frame, set
    only when the loader mapped the splat into that frame (nerfstudio, gsplat, a scene.yaml
    transform); None when both frames are one. `peak` (format 1.3; in summary.json
    `best_view_score` since 1.6, `peak` before): the object's best single view for the task, as a
    margin between the calibrated likelihood means (0 = a typical irrelevant view, 1 = a typical
    relevant one, above 1 for a view better than typical; `fusion.peak`), the score the "not
    found" rule thresholds; None when the run did not record it. `score` (format 1.4): the number the task's objects are ranked by
    (`Result.ranked_by` names it; for 'evidence' the mean log-odds of the object's
    Gaussians), so ranks follow it even where `probability` saturates; None before 1.4.
    `world_centroid` / `world_box` (format 1.4): the same in the data's own world frame (COLMAP's,
    undoing nerfstudio's `applied_transform`), set only when that frame differs from the cameras'
    frame (`Result.capture_to_world`). `key` (format 1.5): the object's content key
    (`results.keys`): equal in two runs exactly when the object holds the same Gaussians."""

    object_id: int
    probability: float
    num_gaussians: int
    centroid: np.ndarray
    box: OrientedBox
    export: str | None = None
    capture_centroid: np.ndarray | None = None
    capture_box: OrientedBox | None = None
    peak: float | None = None
    score: float | None = None
    world_centroid: np.ndarray | None = None
    world_box: OrientedBox | None = None
    key: str | None = None

    @property
    def best_view_score(self) -> float | None:
        """`peak` by its user-facing name (the summary.json key since format 1.6)."""
        return self.peak

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "object_id": int(self.object_id),
            "probability": float(self.probability),
            "num_gaussians": int(self.num_gaussians),
            "centroid": np.asarray(self.centroid, dtype=np.float64).tolist(),
            "box": self.box.to_dict(),
            "export": self.export,
        }
        if self.key is not None:
            out["key"] = self.key
        if self.peak is not None:
            out[BEST_VIEW_SCORE_KEY] = float(self.peak)
            out[LEGACY_PEAK_KEY] = float(self.peak)  # for 1.3-1.5 readers, this format version only
        if self.score is not None:
            out["score"] = float(self.score)
        if self.capture_centroid is not None and self.capture_box is not None:
            out["capture_frame"] = {
                "centroid": np.asarray(self.capture_centroid, dtype=np.float64).tolist(),
                "box": self.capture_box.to_dict(),
            }
        if self.world_centroid is not None and self.world_box is not None:
            out["world_frame"] = {
                "centroid": np.asarray(self.world_centroid, dtype=np.float64).tolist(),
                "box": self.world_box.to_dict(),
            }
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SelectedObject:
        try:
            centroid = np.asarray(data["centroid"], dtype=np.float64)
            if centroid.shape != (3,):
                raise InputError(f"result summary: centroid must have 3 values, got {centroid.shape}")
            capture_centroid, capture_box = _framed(data.get("capture_frame"), "capture_frame")
            world_centroid, world_box = _framed(data.get("world_frame"), "world_frame")
            return cls(
                object_id=int(data["object_id"]),
                probability=float(data["probability"]),
                num_gaussians=int(data["num_gaussians"]),
                centroid=centroid,
                box=OrientedBox.from_dict(data["box"]),
                export=data.get("export"),
                capture_centroid=capture_centroid,
                capture_box=capture_box,
                peak=_best_view_score(data),
                score=None if data.get("score") is None else float(data["score"]),
                world_centroid=world_centroid,
                world_box=world_box,
                key=None if data.get("key") is None else str(data["key"]),
            )
        except KeyError as exc:
            raise InputError(f"result summary: selected object missing field {exc.args[0]!r}") from None


def _best_view_score(data: dict[str, Any]) -> float | None:
    """An object's best-view score from either key (`best_view_score`, or 1.3-1.5's `peak`)."""
    value = data.get(BEST_VIEW_SCORE_KEY, data.get(LEGACY_PEAK_KEY))
    return None if value is None else float(value)


def _framed(block: Any, name: str) -> tuple[np.ndarray | None, OrientedBox | None]:
    """(centroid (3,), box) of an optional `capture_frame` / `world_frame` block, (None, None)
    when absent (older formats, or the frame is the splat's)."""
    if block is None:
        return None, None
    centroid = np.asarray(block["centroid"], dtype=np.float64)
    if centroid.shape != (3,):
        raise InputError(f"result summary: {name} centroid must have 3 values")
    return centroid, OrientedBox.from_dict(block["box"])


@dataclass
class Result:
    """A task-driven semantic map.

    object_ids: (N,) integer, the object of each Gaussian, -1 = none (pruned, never observed, or
        removed as a floater of a selected object by the kNN filter).
    probabilities: (O, T + 1) float32, p(task | object) per object; the last column is the null task.
        The normalised conditional the AIB clustered on (a distribution over tasks + null).
    relevance: optional (O, T) float32, p(y = 1 | object): each task's own probability that the
        object is relevant (the mean fused probability of its Gaussians), the score objects are
        pruned and selected by (format 1.1; None in 1.0 results).
    selections: task -> its top-k objects, most probable first.
    primitive_ids: optional (N,) integer primitive of each Gaussian, -1 = none.
    parameters / models / timings_s: provenance: pipeline parameters, model ids, seconds per stage.
    num_primitives: primitive count when known without `primitive_ids` (the memory table needs it).
    splat_to_capture: optional (4, 4) similarity the loader applied to the splat file's Gaussians
        to put them in the cameras' frame (format 1.2; None = one frame). Selections carry both.
    layout: the scene layout the loader recognised ('inria', 'nerfstudio', 'gsplat', ...), or ''.
    not_found: task -> why it has no answer (format 1.3): the task's selection is empty because
        its best object did not carry enough evidence (`objects.not_found`). Empty before 1.3.
    capture_to_world: optional (4, 4) similarity from the cameras' frame to the data's own world
        frame (format 1.4): nerfstudio's transforms.json poses are `applied_transform @ world`,
        so this is its inverse; None when the camera file is in the world frame itself.
    scene_scale: the run's scene scale and every length derived from it (format 1.4;
        `scene.scale.SceneLengths.record`), None before 1.4.
    splat_digest: content digest of the splat the run read (`job.content_keys.splat_digest`;
        format 1.5, '' before): binds the object keys to the scene.
    keys: each object row's content key (`results.keys`; format 1.5), None until computed:
        `content_keys()` fills it.
    ranked_by: what `SelectedObject.score` is, the run's `selection_score` (format 1.4: 'evidence', 'relevance' or
        'conditional'; '' before 1.4).
    """

    tasks: list[str]
    object_ids: np.ndarray
    probabilities: np.ndarray
    selections: dict[str, list[SelectedObject]]
    primitive_ids: np.ndarray | None = None
    relevance: np.ndarray | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    models: dict[str, Any] = field(default_factory=dict)
    timings_s: dict[str, float] = field(default_factory=dict)
    num_primitives: int | None = None
    splat_to_capture: np.ndarray | None = None
    layout: str = ""
    not_found: dict[str, NotFound] = field(default_factory=dict)
    capture_to_world: np.ndarray | None = None
    scene_scale: dict[str, Any] | None = None
    ranked_by: str = ""
    splat_digest: str = ""
    keys: list[str] | None = None
    format_version: str = FORMAT_VERSION

    @property
    def num_gaussians(self) -> int:
        return int(np.asarray(self.object_ids).shape[0])

    @property
    def num_objects(self) -> int:
        return int(np.asarray(self.probabilities).shape[0])

    @property
    def task_scores(self) -> np.ndarray:
        """(O, T) each task's score of each object: `relevance`, or for 1.0 results (which have
        none) the conditional without its null column."""
        return task_scores(self.probabilities, self.relevance)

    def content_keys(self) -> list[str]:
        """Each object row's content key, as read or written, else computed from the id map."""
        if self.keys is None:
            self.keys = object_keys(self.object_ids, self.num_objects, self.splat_digest)
        return self.keys

    def validate(self) -> None:
        """Raise InputError unless every array and selection is consistent."""
        ids = np.asarray(self.object_ids)
        if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
            raise InputError(f"result: object_ids must be a 1-D integer array, got {ids.dtype} {ids.shape}")
        probs = np.asarray(self.probabilities)
        if probs.ndim != 2 or probs.shape[1] != len(self.tasks) + 1:
            raise InputError(
                f"result: probabilities must be (objects, tasks + 1) = (O, {len(self.tasks) + 1}), got {probs.shape}"
            )
        if not np.isfinite(probs).all():
            raise InputError("result: probabilities contain NaN or infinity")
        if ids.size and (ids.min() < -1 or ids.max() >= probs.shape[0]):
            raise InputError(
                f"result: object_ids must lie in [-1, {probs.shape[0]}), got [{ids.min()}, {ids.max()}]"
            )
        if self.relevance is not None:
            rel = np.asarray(self.relevance)
            if rel.shape != (probs.shape[0], len(self.tasks)) or not np.isfinite(rel).all():
                raise InputError(
                    f"result: relevance must be finite, (objects, tasks) = ({probs.shape[0]}, {len(self.tasks)}),"
                    f" got {rel.shape}"
                )
        if self.primitive_ids is not None:
            prim = np.asarray(self.primitive_ids)
            if prim.shape != ids.shape or not np.issubdtype(prim.dtype, np.integer):
                raise InputError(f"result: primitive_ids must be an integer array of shape {ids.shape}")
            if prim.size and prim.min() < -1:
                raise InputError("result: primitive_ids below -1")
        if self.keys is not None and len(self.keys) != probs.shape[0]:
            raise InputError(f"result: {len(self.keys)} object keys for {probs.shape[0]} objects")
        if len(set(self.tasks)) != len(self.tasks):
            raise InputError("result: duplicate task names")
        for task, objs in self.selections.items():
            if task not in self.tasks:
                raise InputError(f"result: selection for unknown task {task!r}")
            for obj in objs:
                if not 0 <= obj.object_id < probs.shape[0]:
                    raise InputError(f"result: task {task!r} selects unknown object {obj.object_id}")
        for task in self.not_found:
            if task not in self.tasks:
                raise InputError(f"result: not_found for unknown task {task!r}")
            if self.selections.get(task):
                raise InputError(f"result: task {task!r} is both answered and not found")

    def counts(self) -> dict[str, int | None]:
        ids = np.asarray(self.object_ids)
        prims = self.num_primitives
        if prims is None and self.primitive_ids is not None and np.asarray(self.primitive_ids).size:
            prims = int(np.unique(self.primitive_ids[self.primitive_ids >= 0]).size)
        return {
            "gaussians": self.num_gaussians,
            "gaussians_in_objects": int(np.count_nonzero(ids >= 0)),
            "primitives": prims,
            "objects": self.num_objects,
            "tasks": len(self.tasks),
            "selected_objects": len({o.object_id for objs in self.selections.values() for o in objs}),
        }


def normalise_prefix(prefix: str) -> str:
    """'' or a key prefix ending in '/'."""
    return prefix if not prefix or prefix.endswith("/") else prefix + "/"


# ---- array encodings ------------------------------------------------------------------------


def id_dtype(max_id: int) -> np.dtype:
    """Smallest unsigned little-endian type whose maximum (the sentinel) exceeds `max_id`."""
    for dtype in ID_DTYPES:
        if max_id < np.iinfo(dtype).max:
            return dtype
    raise InputError(f"result: id {max_id} does not fit in uint32 with a sentinel")


def encode_ids(ids: np.ndarray) -> tuple[np.ndarray, int]:
    """(-1 = none) ids -> (unsigned array with the sentinel for none, sentinel)."""
    ids = np.asarray(ids)
    dtype = id_dtype(int(ids.max()) if ids.size else 0)
    sentinel = int(np.iinfo(dtype).max)
    return np.where(ids < 0, sentinel, ids).astype(dtype), sentinel


def decode_ids(stored: np.ndarray, sentinel: int) -> np.ndarray:
    """Unsigned ids with a sentinel -> int64 ids with -1 for none."""
    out = stored.astype(np.int64)
    out[stored == sentinel] = -1
    return out


ZLIB_LEVEL = 6
LZMA_PRESET = 0
"""Compression effort of stored arrays. The per-Gaussian id arrays dominate a result's bytes and
its writing time: at 400 k Gaussians, lzma preset 6 and zlib 9 took 1.4 s for 4-8 % fewer bytes
than preset 0 and level 6 (0.5 s). The reader accepts any level (the codec name is what it reads)."""


def compress(raw: bytes) -> tuple[str, bytes]:
    """The smallest of raw, zlib (`ZLIB_LEVEL`) and lzma (xz, `LZMA_PRESET`) encodings: (codec, bytes)."""
    options = [
        ("raw", raw),
        ("zlib", zlib.compress(raw, ZLIB_LEVEL)),
        ("lzma", lzma.compress(raw, preset=LZMA_PRESET)),
    ]
    return min(options, key=lambda item: len(item[1]))


def decompress(codec: str, data: bytes, *, expected: int, name: str) -> bytes:
    """Inverse of `compress`, refusing output longer than `expected` bytes (a hostile archive)."""
    try:
        if codec == "raw":
            raw = data
        elif codec == "zlib":
            d = zlib.decompressobj()
            raw = d.decompress(data, expected + 1)
        elif codec == "lzma":
            raw = lzma.LZMADecompressor().decompress(data, max_length=expected + 1)
        else:
            raise InputError(f"result: {name}: unknown codec {codec!r} (expected one of {CODECS})")
    except (zlib.error, lzma.LZMAError) as exc:
        raise InputError(f"result: {name}: corrupt {codec} data ({exc})") from None
    if len(raw) != expected:
        raise InputError(f"result: {name}: expected {expected} bytes after decompression, got {len(raw)}")
    return raw


def encode_array(
    array: np.ndarray, *, file: str, sentinel: int | None = None
) -> tuple[dict[str, Any], bytes]:
    """(descriptor for summary.json, stored bytes) of a numeric array."""
    arr = np.ascontiguousarray(array)
    arr = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    raw = arr.tobytes()
    codec, data = compress(raw)
    desc: dict[str, Any] = {
        "file": file,
        "dtype": arr.dtype.str,
        "shape": list(arr.shape),
        "codec": codec,
        "raw_bytes": len(raw),
        "stored_bytes": len(data),
        "sha256": hashlib.sha256(raw).hexdigest(),
    }
    if sentinel is not None:
        desc["sentinel"] = sentinel
    return desc, data


_ALLOWED_DTYPES = {"<u1", "|u1", "<u2", "<u4", "<f2", "<f4", "<f8", "<i4", "<i8"}


def decode_array(desc: dict[str, Any], data: bytes, *, name: str) -> np.ndarray:
    """Array from its descriptor and stored bytes, checking dtype, size and checksum."""
    try:
        dtype_str, shape, codec = str(desc["dtype"]), [int(s) for s in desc["shape"]], str(desc["codec"])
        digest = str(desc["sha256"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"result: {name}: malformed array descriptor ({exc!r})") from None
    if dtype_str not in _ALLOWED_DTYPES:
        raise InputError(f"result: {name}: unsupported dtype {dtype_str!r}")
    if any(s < 0 for s in shape):
        raise InputError(f"result: {name}: negative shape {shape}")
    dtype = np.dtype(dtype_str)
    expected = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = decompress(codec, data, expected=expected, name=name)
    if hashlib.sha256(raw).hexdigest() != digest:
        raise InputError(f"result: {name}: checksum mismatch (the file is corrupt or was replaced)")
    return np.frombuffer(raw, dtype=dtype).reshape(shape).copy()
