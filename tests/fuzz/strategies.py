"""Structure-aware hypothesis generators for every input the service accepts.

Each generator starts from the real format (a well-formed PLY header, a transforms.json with
rigid poses, a COLMAP model, a zip of images) and mutates it at the level a hostile client
would: wrong counts and types, missing or duplicated fields, absurd numbers, path names that
climb out or are absolute, truncated or extended bodies, flipped bytes. Mostly-valid inputs
reach the deep checks; fully random ones reach the shallow ones.
"""

from __future__ import annotations

import io
import json
import math
import random
import struct
import tarfile
import zipfile

import numpy as np
from hypothesis import strategies as st

from bayesian_fields_core.scene.colmap import MODELS

IMAGE_NAMES = ("frame_000.png", "frame_001.png")
"""Images every fuzzed scene folder really contains (see `test_fuzz_library.scene_folder`)."""
IMAGE_SIZE = (16, 12)

# -- small building blocks -----------------------------------------------------------------

SPECIAL_FLOATS = st.sampled_from(
    [0.0, -0.0, 1.0, -1.0, 1e-45, 1e-12, 1e7, 1e12, 1e38, 3.5e38, -1e30, math.nan, math.inf, -math.inf]
)
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32), SPECIAL_FLOATS, st.integers(-(2**70), 2**70)
)
small_text = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)

json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), numbers, small_text),
    lambda children: st.one_of(
        st.lists(children, max_size=5), st.dictionaries(small_text, children, max_size=5)
    ),
    max_leaves=20,
)

#: Names a camera file may give an image: the real ones, near misses and every escape kind.
path_names = st.one_of(
    st.sampled_from(IMAGE_NAMES),
    st.sampled_from(
        [
            "/etc/passwd",
            "/etc/hostname",
            "../../../../../../etc/passwd",
            "images/../../x.png",
            "images/../images/frame_000.png",
            "frame_000",
            "",
            ".",
            "..",
            "images/",
            "a\x00b.png",
            "~/x.png",
            "C:\\windows\\x.png",
            "n" * 300 + ".png",
            "d/" * 300 + "x.png",
            "frame_000.png/x",
        ]
    ),
    st.builds(lambda n: "images/" + n, st.sampled_from(IMAGE_NAMES)),
    st.text(max_size=20),
)


def rare(draw, p: float = 0.15) -> bool:
    """True with probability `p`. Hypothesis favours boundary values (0, the first choice), so a
    gate like `integers(0, 9) == 0` fires far more often than 1 in 10 (so do `st.randoms()`); a
    `random.Random` seeded from a drawn integer does not."""
    return random.Random(draw(st.integers(0, 2**32 - 1))).random() < p


def flip_bytes(data: bytes, draw) -> bytes:
    """Overwrite, delete, insert or truncate a few bytes of `data`."""
    blob = bytearray(data)
    for _ in range(draw(st.integers(0, 4))):
        op = draw(st.sampled_from(["set", "del", "ins", "cut"]))
        pos = draw(st.integers(0, max(len(blob) - 1, 0)))
        if op == "set" and blob:
            blob[pos] = draw(st.integers(0, 255))
        elif op == "del" and blob:
            del blob[pos : pos + draw(st.integers(1, 16))]
        elif op == "ins":
            blob[pos:pos] = draw(st.binary(max_size=16))
        elif op == "cut":
            del blob[pos:]
    return bytes(blob)


# -- PLY -----------------------------------------------------------------------------------

PLY_TYPES = ["float", "double", "uchar", "int", "short", "uint", "char", "float32", "int8", "list", "bogus"]
REQUIRED_PROPS = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
REQUIRED_PROPS += [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]


@st.composite
def ply_files(draw) -> bytes:
    """A splat PLY: a plausible header with mutations, a body sized right, wrong or random."""
    fmt = draw(
        st.sampled_from(["binary_little_endian", "binary_big_endian", "ascii", "binary_middle_endian"])
    )
    rest = draw(st.sampled_from([0, 9, 24, 45, 3, 10]))
    props = [(n, "float") for n in REQUIRED_PROPS] + [(f"f_rest_{i}", "float") for i in range(rest)]
    if draw(st.booleans()):
        props += [(n, draw(st.sampled_from(PLY_TYPES[:7]))) for n in ("nx", "ny", "nz")]
    for _ in range(draw(st.integers(1, 3)) if rare(draw, 0.4) else 0):  # mutate the property list
        op = draw(st.sampled_from(["drop", "retype", "dup", "add"]))
        i = draw(st.integers(0, len(props) - 1))
        if op == "drop":
            props.pop(i)
        elif op == "retype":
            props[i] = (props[i][0], draw(st.sampled_from(PLY_TYPES)))
        elif op == "dup":
            props.append(props[i])
        else:
            props.append((draw(st.from_regex(r"[a-z_][a-z0-9_]{0,8}", fullmatch=True)), "float"))
    n = draw(st.sampled_from([0, 10**9, 2**63, 10**40])) if rare(draw, 0.1) else draw(st.integers(1, 6))
    lines = ["ply", f"format {fmt} 1.0"]
    if rare(draw, 0.2):
        lines.append(f"element face {draw(st.integers(0, 3))}")
        lines.append("property list uchar int vertex_indices" if draw(st.booleans()) else "property float q")
    lines.append(f"element vertex {n}")
    for name, t in props:
        lines.append(f"property list uchar float {name}" if t == "list" else f"property {t} {name}")
    if rare(draw, 0.2):
        lines.append(f"element extra {draw(st.integers(0, 3))}")
        lines.append("property float e")
    lines.append("end_header")
    header = "\n".join(lines) + "\n"
    if rare(draw, 0.05):
        header = header.replace("end_header", draw(st.sampled_from(["", "end_headr", "end_header extra"])))
    rows = n if n <= 6 else 2
    count = max(len(props) * (rows + (draw(st.sampled_from([-1, 1, 2])) if rare(draw, 0.3) else 0)), 0)
    # Values from a drawn seed (fast) with special values injected at drawn positions.
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    values = rng.normal(0.0, draw(st.sampled_from([1e3, 1e30])) if rare(draw, 0.2) else 1.0, count)
    for _ in range(draw(st.integers(1, 3)) if rare(draw, 0.3) else 0):
        if count:
            values[draw(st.integers(0, count - 1))] = draw(SPECIAL_FLOATS)
    if fmt == "ascii":
        width = len(props) or 1
        body = "\n".join(
            " ".join(repr(float(v)) for v in values[i : i + width]) for i in range(0, count, width)
        )
        body = (body + "\n").encode()
    else:
        order = ">" if fmt == "binary_big_endian" else "<"
        with np.errstate(over="ignore"):
            body = values.astype(order + "f4").tobytes()
    blob = header.encode("ascii", "replace") + body
    if rare(draw, 0.2):
        blob = flip_bytes(blob, draw)
    return blob


# -- camera files --------------------------------------------------------------------------


def _rigid(draw) -> list[list[float]]:
    angle = draw(st.floats(-math.pi, math.pi))
    c, s = math.cos(angle), math.sin(angle)
    t = [draw(st.floats(-5, 5)) for _ in range(3)]
    return [[c, -s, 0.0, t[0]], [s, c, 0.0, t[1]], [0.0, 0.0, 1.0, t[2]], [0.0, 0.0, 0.0, 1.0]]


def _maybe(draw, good, bad=json_values):
    """`good` most of the time, a hostile value sometimes."""
    return draw(bad) if rare(draw, 0.08) else good


@st.composite
def transforms_docs(draw) -> bytes:
    """A transforms.json: shared and per-frame intrinsics, rigid poses, path fields, mutations."""
    w, h = IMAGE_SIZE
    top = {
        "camera_model": _maybe(
            draw, "OPENCV", st.sampled_from(["OPENCV_FISHEYE", "EQUIRECTANGULAR", 3, None])
        ),
        "fl_x": _maybe(draw, 20.0, numbers),
        "fl_y": _maybe(draw, 20.0, numbers),
        "w": _maybe(draw, w, numbers),
        "h": _maybe(draw, h, numbers),
    }
    for key in draw(st.lists(st.sampled_from(["cx", "cy", "k1", "k2", "p1", "k4", "camera_angle_x",
                                               "camera_angle_y", "depth_unit_scale_factor"]), max_size=3)):  # fmt: skip
        top[key] = draw(numbers)
    for key in draw(st.lists(st.sampled_from(list(top)), max_size=2)):
        top.pop(key, None)
    frames = []
    for _ in range(draw(st.integers(1, 3)) if not rare(draw, 0.05) else 0):
        name = draw(path_names) if rare(draw, 0.3) else "images/" + draw(st.sampled_from(IMAGE_NAMES))
        entry = {"file_path": name, "transform_matrix": _maybe(draw, _rigid(draw))}
        for key in draw(st.lists(st.sampled_from(["depth_file_path", "mask_path", "fl_x", "w"]), max_size=2)):
            entry[key] = draw(st.one_of(path_names, numbers)) if key.endswith("path") else draw(numbers)
        frames.append(_maybe(draw, entry))
    doc = {**top, "frames": _maybe(draw, frames)}
    return _encode(draw, doc)


@st.composite
def cameras_json_docs(draw) -> bytes:
    """An INRIA cameras.json list with mutated entries."""
    w, h = IMAGE_SIZE
    entries = []
    for i in range(draw(st.integers(1, 3)) if not rare(draw, 0.05) else 0):
        rigid = _rigid(draw)
        entry = {
            "id": i,
            "img_name": (
                draw(path_names) if rare(draw, 0.3) else draw(st.sampled_from(IMAGE_NAMES))
            ).removesuffix(".png"),
            "width": _maybe(draw, w, numbers),
            "height": _maybe(draw, h, numbers),
            "position": _maybe(draw, [r[3] for r in rigid[:3]]),
            "rotation": _maybe(draw, [r[:3] for r in rigid[:3]]),
            "fx": _maybe(draw, 20.0, numbers),
            "fy": _maybe(draw, 20.0, numbers),
        }
        for key in draw(st.lists(st.sampled_from(list(entry)), max_size=2)):
            entry.pop(key, None)
        entries.append(_maybe(draw, entry))
    return _encode(draw, _maybe(draw, entries))


def _encode(draw, doc) -> bytes:
    text = json.dumps(doc, allow_nan=True)
    choice = draw(st.sampled_from([0, 1, 2])) if rare(draw, 0.15) else 3
    if choice == 0:
        depth = draw(st.sampled_from([10, 1000, 100_000]))
        text = "[" * depth + text + "]" * depth  # past the recursion limit
    elif choice == 1:
        text = text.replace("20.0", "2" + "0" * 5000, 1)  # past Python's int-digits limit
    blob = text.encode("utf-8")
    return flip_bytes(blob, draw) if choice == 2 else blob


@st.composite
def colmap_text_models(draw) -> tuple[bytes, bytes]:
    """(cameras.txt, images.txt) with valid-looking lines, mutated tokens and junk lines."""
    w, h = IMAGE_SIZE
    cams, imgs = ["# cameras"], ["# images"]
    for cid in range(1, (0 if rare(draw, 0.05) else draw(st.integers(1, 3))) + 1):
        model, nparams = (
            draw(st.sampled_from(list(MODELS.values()) + [("BOGUS", 2)]))
            if rare(draw, 0.2)
            else draw(st.sampled_from([("PINHOLE", 4), ("SIMPLE_PINHOLE", 3), ("OPENCV", 8)]))
        )
        nparams += draw(st.sampled_from([-1, 1])) if rare(draw, 0.1) else 0
        params = [repr(draw(numbers)) if rare(draw, 0.1) else "10" for _ in range(nparams)]
        size = [str(_maybe(draw, w, numbers)), str(_maybe(draw, h, numbers))]
        cams.append(" ".join([str(cid), model, *size, *params]))
    for iid in range(1, (0 if rare(draw, 0.05) else draw(st.integers(1, 3))) + 1):
        pose = [repr(_maybe(draw, v, numbers)) for v in (1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 3.0)]
        cid = _maybe(draw, 1, st.integers(-2, 5))
        name = draw(path_names) if rare(draw, 0.3) else draw(st.sampled_from(IMAGE_NAMES))
        imgs.append(" ".join([str(iid), *pose, str(cid), name.replace("\n", "")]))
        imgs.append(draw(st.sampled_from(["", "1.0 2.0 -1", "junk"])))
    if rare(draw, 0.15):
        (cams if draw(st.booleans()) else imgs).append(draw(st.text(max_size=40)))
    return "\n".join(cams).encode("utf-8", "surrogatepass"), "\n".join(imgs).encode("utf-8", "surrogatepass")


@st.composite
def colmap_binary_models(draw) -> tuple[bytes, bytes]:
    """(cameras.bin, images.bin) packed like COLMAP, with lying counts and flipped bytes."""
    w, h = IMAGE_SIZE
    n_cams = 0 if rare(draw, 0.05) else draw(st.integers(1, 3))
    cams = struct.pack("<Q", _maybe(draw, n_cams, st.sampled_from([0, 2**64 - 1, 10**6])))
    for cid in range(1, n_cams + 1):
        mid = draw(st.integers(-5, 20)) if rare(draw, 0.2) else draw(st.sampled_from([0, 1, 4]))
        nparams = MODELS.get(mid, ("", 3))[1]
        size = (_maybe(draw, w, st.integers(0, 2**64 - 1)), _maybe(draw, h, st.integers(0, 2**64 - 1)))
        params = [draw(st.one_of(st.just(10.0), st.floats())) for _ in range(nparams)]
        cams += struct.pack(f"<iiQQ{nparams}d", cid, mid, *size, *params)
    n_imgs = 0 if rare(draw, 0.05) else draw(st.integers(1, 3))
    imgs = struct.pack("<Q", _maybe(draw, n_imgs, st.sampled_from([0, 2**64 - 1])))
    for iid in range(1, n_imgs + 1):
        q = [draw(st.one_of(st.just(v), st.floats())) for v in (1.0, 0.0, 0.0, 0.0)]
        name = draw(path_names) if rare(draw, 0.3) else draw(st.sampled_from(IMAGE_NAMES))
        name = name.encode("utf-8", "surrogatepass").replace(b"\0", b"")
        npoints = 2**60 if rare(draw, 0.05) else draw(st.sampled_from([0, 1]))
        imgs += struct.pack("<i7di", iid, *q, 0.1, 0.2, 3.0, _maybe(draw, 1, st.integers(-3, 5)))
        imgs += name + b"\0" + struct.pack("<Q", npoints) + bytes(24 * min(npoints, 1))
    if rare(draw):
        cams = flip_bytes(cams, draw)
    if rare(draw):
        imgs = flip_bytes(imgs, draw)
    return cams, imgs


# -- archives ------------------------------------------------------------------------------

member_names = st.one_of(
    st.sampled_from(IMAGE_NAMES),
    st.sampled_from(IMAGE_NAMES),
    st.builds(lambda n: "images/" + n, st.sampled_from(IMAGE_NAMES)),
    path_names,
    st.sampled_from(["a", "a/b", "a/b/c.png", "images/", "./x.png", "x/./y.png", "é" * 130, "dir/"]),
)


@st.composite
def zip_archives(draw) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for _ in range(draw(st.integers(0, 5))):
            name = draw(member_names).replace("\x00", "") or "x"
            info = zipfile.ZipInfo(name)
            info.compress_type = draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED,
                                                       zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA]))  # fmt: skip
            kind = draw(st.sampled_from(["symlink", "fifo", "dir"])) if rare(draw, 0.15) else "file"
            mode = {"file": 0o100644, "symlink": 0o120777, "fifo": 0o010644, "dir": 0o040755}[kind]
            info.external_attr = mode << 16
            zf.writestr(info, draw(st.binary(max_size=64)))
    blob = buf.getvalue()
    if rare(draw, 0.25):
        blob = bytearray(blob)
        if draw(st.booleans()) and len(blob) > 10:  # an unknown compression method in the local header
            blob[8:10] = draw(st.integers(0, 65535)).to_bytes(2, "little")
        blob = flip_bytes(bytes(blob), draw)
    return blob


@st.composite
def tar_archives(draw) -> bytes:
    buf = io.BytesIO()
    mode = draw(st.sampled_from(["w", "w:gz", "w:bz2", "w:xz"]))
    fmt = draw(st.sampled_from([tarfile.PAX_FORMAT, tarfile.GNU_FORMAT, tarfile.USTAR_FORMAT]))
    with tarfile.open(fileobj=buf, mode=mode, format=fmt) as tf:
        for _ in range(draw(st.integers(0, 5))):
            name = draw(member_names).replace("\x00", "") or "x"
            if fmt == tarfile.USTAR_FORMAT and len(name.encode("utf-8", "surrogatepass")) > 100:
                name = name[:50]
            info = tarfile.TarInfo(name)
            hostile = (tarfile.DIRTYPE, tarfile.SYMTYPE, tarfile.LNKTYPE, tarfile.FIFOTYPE)
            info.type = draw(st.sampled_from(hostile)) if rare(draw, 0.15) else tarfile.REGTYPE
            data = draw(st.binary(max_size=64)) if info.type == tarfile.REGTYPE else b""
            info.size = len(data)
            info.linkname = draw(st.sampled_from(["/etc/passwd", "../x", "a"]))
            try:
                tf.addfile(info, io.BytesIO(data))
            except (ValueError, UnicodeError):  # a name this format cannot hold: leave it out
                continue
    blob = buf.getvalue()
    return flip_bytes(blob, draw) if rare(draw, 0.25) else blob


# -- task lists ----------------------------------------------------------------------------

task_texts = st.one_of(
    st.text(st.characters(blacklist_categories=("Cs",)), max_size=80),
    st.sampled_from(["get mug", "  get   dish soap ", "", " ", "x" * 300, "get\tmug", "get mug"]),
)
task_lists = st.one_of(
    st.lists(task_texts, max_size=30),
    st.lists(
        st.dictionaries(st.sampled_from(["task", "name", "text", "other"]), task_texts, max_size=2),
        max_size=5,
    ),
    st.builds(lambda t: {"tasks": t}, st.lists(task_texts, max_size=5)),
    json_values,
)
