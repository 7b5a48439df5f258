"""The vocabulary of the synthetic benchmark: colours, shapes, compound objects and their surfaces.

The synthetic scenes (``eval/synthetic.py``) and the tiny test CLIP (``scripts/train_tiny_clip.py``)
must agree on what objects exist and what they are called, so both draw from this one module.
Objects are unions of *parts*; each part is a primitive surface (box, sphere, frustum, torus, rectangle)
sampled uniformly by area, which is what a trained splat approximates: flat Gaussians on surfaces.
Every object kind is built in a local frame with z up and its base resting on z = 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

# Distinct, saturated colours (linear RGB in [0, 1]); the background uses neutral tones far from them.
COLOURS: dict[str, tuple[float, float, float]] = {
    "red": (0.85, 0.10, 0.10),
    "green": (0.10, 0.65, 0.20),
    "blue": (0.10, 0.25, 0.85),
    "yellow": (0.95, 0.85, 0.10),
    "orange": (0.95, 0.50, 0.05),
    "purple": (0.55, 0.15, 0.75),
    "cyan": (0.10, 0.80, 0.85),
}

# Colours of the room and of the uncoloured parts of compound objects.
NEUTRALS: dict[str, tuple[float, float, float]] = {
    "wood": (0.52, 0.36, 0.22),
    "floor": (0.42, 0.42, 0.44),
    "wall": (0.86, 0.84, 0.79),
    "metal": (0.22, 0.22, 0.24),
}

# Names of the room's structures, as instances and as captions ("table", "floor", "wall").
BACKGROUND_KINDS: tuple[str, ...] = ("table", "floor", "wall")


@dataclass(frozen=True)
class Part:
    """One primitive surface of an object, placed in the object's local frame.

    primitive: "box" (half_extents), "sphere" (radius), "frustum" (r_bottom, r_top, height,
    cap_bottom, cap_top; cylinders and cones are frustums), "torus" (major, minor), "rect" (half
    sizes in x and y, normal +z). rotation/translation map part coordinates to object coordinates.
    colour: "main" takes the object's colour; any other value names a NEUTRALS entry.
    min_radius: drop samples closer than this to the object's z axis (a mug handle inside the body).
    """

    primitive: str
    params: dict[str, float] = field(default_factory=dict)
    rotation: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    colour: str = "main"
    min_radius: float = 0.0


def _rot_x(deg: float) -> tuple[tuple[float, ...], ...]:
    a = np.deg2rad(deg)
    c, s = float(np.cos(a)), float(np.sin(a))
    return ((1.0, 0.0, 0.0), (0.0, c, -s), (0.0, s, c))


def _cube(k: float) -> list[Part]:
    h = 0.055 * k
    return [Part("box", {"hx": h, "hy": h, "hz": h}, translation=(0.0, 0.0, h))]


def _sphere(k: float) -> list[Part]:
    r = 0.055 * k
    return [Part("sphere", {"radius": r}, translation=(0.0, 0.0, r))]


def _cylinder(k: float) -> list[Part]:
    return [Part("frustum", {"r_bottom": 0.04 * k, "r_top": 0.04 * k, "height": 0.14 * k, "cap_top": 1})]


def _cone(k: float) -> list[Part]:
    return [Part("frustum", {"r_bottom": 0.055 * k, "r_top": 0.0, "height": 0.13 * k, "cap_bottom": 1})]


def _torus(k: float) -> list[Part]:
    minor = 0.018 * k
    return [Part("torus", {"major": 0.055 * k, "minor": minor}, translation=(0.0, 0.0, minor))]


def _mug(k: float) -> list[Part]:
    """A cup body open at the top plus a vertical ring handle on its +x side."""
    r, h = 0.045 * k, 0.10 * k
    body = Part("frustum", {"r_bottom": r, "r_top": r, "height": h, "cap_bottom": 1})
    handle = Part(
        "torus",
        {"major": 0.03 * k, "minor": 0.008 * k},
        rotation=_rot_x(90.0),
        translation=(r, 0.0, 0.5 * h),
        min_radius=r,
    )
    return [body, handle]


def _lamp(k: float) -> list[Part]:
    """A desk lamp: metal base and stem, coloured conical shade open at both ends."""
    base = Part(
        "frustum",
        {"r_bottom": 0.055 * k, "r_top": 0.05 * k, "height": 0.012 * k, "cap_top": 1},
        colour="metal",
    )
    stem = Part(
        "frustum",
        {"r_bottom": 0.008 * k, "r_top": 0.008 * k, "height": 0.2 * k},
        translation=(0.0, 0.0, 0.012 * k),
        colour="metal",
    )
    shade = Part(
        "frustum",
        {"r_bottom": 0.085 * k, "r_top": 0.04 * k, "height": 0.09 * k},
        translation=(0.0, 0.0, 0.16 * k),
    )
    return [base, stem, shade]


# Object kinds: simple shapes and compounds (several parts, one object), so tasks need different
# granularities. The value builds the parts for a size factor k (about 1).
KINDS: dict[str, Callable[[float], list[Part]]] = {
    "cube": _cube,
    "sphere": _sphere,
    "cylinder": _cylinder,
    "cone": _cone,
    "torus": _torus,
    "mug": _mug,
    "lamp": _lamp,
}
COMPOUND_KINDS: frozenset[str] = frozenset({"mug", "lamp"})

# Kinds that may carry a coloured label (capture scenes; tasks "get the red cube with the blue
# label"): their side at local +y (away from a mug's handle, which is at +x) is a surface at a
# known distance from the axis. kind: (surface distance from the axis, label centre height), per
# unit size factor.
LABELLED_KINDS: dict[str, tuple[float, float]] = {
    "cube": (0.055, 0.055),
    "cylinder": (0.04, 0.07),
    "mug": (0.045, 0.05),
}


def plural(word: str) -> str:
    """Regular English plural of a vocabulary noun ("cube" -> "cubes", "torus" -> "toruses")."""
    return word + ("es" if word.endswith("s") else "s")


def object_name(colour: str, kind: str) -> str:
    """The canonical caption of an object: "red cube"."""
    return f"{colour} {kind}"


def canonical_captions() -> list[str]:
    """Every object name of the vocabulary plus the background kinds, in a fixed order."""
    return [object_name(c, k) for k in KINDS for c in COLOURS] + list(BACKGROUND_KINDS)


def part_area(part: Part) -> float:
    """Surface area of a part (before min_radius culling), used to share Gaussians by area."""
    p = part.params
    if part.primitive == "box":
        hx, hy, hz = p["hx"], p["hy"], p["hz"]
        return 8.0 * (hx * hy + hy * hz + hx * hz)
    if part.primitive == "sphere":
        return 4.0 * np.pi * p["radius"] ** 2
    if part.primitive == "frustum":
        r1, r2, h = p["r_bottom"], p["r_top"], p["height"]
        lateral = np.pi * (r1 + r2) * np.hypot(r1 - r2, h)
        return float(lateral + np.pi * (p.get("cap_bottom", 0) * r1**2 + p.get("cap_top", 0) * r2**2))
    if part.primitive == "torus":
        return 4.0 * np.pi**2 * p["major"] * p["minor"]
    if part.primitive == "rect":
        return 4.0 * p["hx"] * p["hy"]
    raise ValueError(f"unknown primitive {part.primitive!r}")


def _sample_box(rng: np.random.Generator, n: int, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    half = np.array([p["hx"], p["hy"], p["hz"]])
    face_area = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
    axis = rng.choice(3, size=n, p=face_area / face_area.sum())
    sign = rng.choice([-1.0, 1.0], size=n)
    pts = rng.uniform(-1.0, 1.0, (n, 3)) * half
    rows = np.arange(n)
    pts[rows, axis] = sign * half[axis]
    normals = np.zeros((n, 3))
    normals[rows, axis] = sign
    return pts, normals


def _sample_sphere(rng: np.random.Generator, n: int, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return p["radius"] * v, v


def _sample_disc(
    rng: np.random.Generator, n: int, radius: float, z: float, up: bool
) -> tuple[np.ndarray, np.ndarray]:
    rho = radius * np.sqrt(rng.uniform(size=n))
    theta = rng.uniform(0.0, 2.0 * np.pi, n)
    pts = np.stack([rho * np.cos(theta), rho * np.sin(theta), np.full(n, z)], axis=1)
    normals = np.zeros((n, 3))
    normals[:, 2] = 1.0 if up else -1.0
    return pts, normals


def _sample_frustum(rng: np.random.Generator, n: int, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Lateral surface (density grows with the radius) plus optional caps, shared by area."""
    r1, r2, h = p["r_bottom"], p["r_top"], p["height"]
    areas = np.array(
        [
            np.pi * (r1 + r2) * np.hypot(r1 - r2, h),
            p.get("cap_bottom", 0) * np.pi * r1**2,
            p.get("cap_top", 0) * np.pi * r2**2,
        ]
    )
    counts = rng.multinomial(n, areas / areas.sum())
    theta = rng.uniform(0.0, 2.0 * np.pi, counts[0])
    u = rng.uniform(size=counts[0])
    if abs(r1 - r2) < 1e-9:
        rho, z = np.full(counts[0], r1), h * u
    else:
        # Inverse CDF of a density proportional to the radius between r2 and r1.
        rho = np.sqrt(r2**2 + u * (r1**2 - r2**2))
        z = h * (r1 - rho) / (r1 - r2)
    side = np.stack([rho * np.cos(theta), rho * np.sin(theta), z], axis=1)
    side_n = np.stack([h * np.cos(theta), h * np.sin(theta), np.full(counts[0], r1 - r2)], axis=1)
    side_n /= np.linalg.norm(side_n, axis=1, keepdims=True)
    bottom = _sample_disc(rng, counts[1], r1, 0.0, up=False)
    top = _sample_disc(rng, counts[2], r2, h, up=True)
    return np.concatenate([side, bottom[0], top[0]]), np.concatenate([side_n, bottom[1], top[1]])


def _sample_torus(rng: np.random.Generator, n: int, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Uniform by area: the tube angle is drawn by rejection with weight (R + r cos phi) / (R + r)."""
    big, small = p["major"], p["minor"]
    phis = np.empty(0)
    while phis.size < n:
        cand = rng.uniform(0.0, 2.0 * np.pi, 2 * n + 16)
        keep = rng.uniform(size=cand.size) < (big + small * np.cos(cand)) / (big + small)
        phis = np.concatenate([phis, cand[keep]])
    phi = phis[:n]
    theta = rng.uniform(0.0, 2.0 * np.pi, n)
    ring = big + small * np.cos(phi)
    pts = np.stack([ring * np.cos(theta), ring * np.sin(theta), small * np.sin(phi)], axis=1)
    normals = np.stack([np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta), np.sin(phi)], axis=1)
    return pts, normals


def _sample_rect(rng: np.random.Generator, n: int, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    pts = np.stack(
        [rng.uniform(-p["hx"], p["hx"], n), rng.uniform(-p["hy"], p["hy"], n), np.zeros(n)], axis=1
    )
    normals = np.zeros((n, 3))
    normals[:, 2] = 1.0
    return pts, normals


_SAMPLERS = {
    "box": _sample_box,
    "sphere": _sample_sphere,
    "frustum": _sample_frustum,
    "torus": _sample_torus,
    "rect": _sample_rect,
}


def sample_part(rng: np.random.Generator, part: Part, density: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit normals on a part's surface in object coordinates, about density per m^2.

    At least 8 points per part, so thin parts (a lamp stem) never vanish at low densities.
    """
    n = max(8, int(round(part_area(part) * density)))
    pts, normals = _SAMPLERS[part.primitive](rng, n, part.params)
    rot = np.asarray(part.rotation, dtype=np.float64)
    pts = pts @ rot.T + np.asarray(part.translation)
    normals = normals @ rot.T
    if part.min_radius > 0.0:
        keep = np.hypot(pts[:, 0], pts[:, 1]) >= part.min_radius
        pts, normals = pts[keep], normals[keep]
    return pts, normals


@dataclass(frozen=True)
class Caption:
    """A phrasing and what it refers to: colour and/or kind (None = any), e.g. "red things", and
    the colour of a label the object must show (None = any object, labelled or not)."""

    text: str
    colour: str | None
    kind: str | None
    label: str | None = None

    def matches(self, colour: str | None, kind: str, label: str | None = None) -> bool:
        """Whether an instance of this colour and kind, showing a label of colour `label` (None: no
        label in sight), is a right answer for the caption."""
        return (
            (self.colour is None or self.colour == colour)
            and (self.kind is None or self.kind == kind)
            and (self.label is None or self.label == label)
        )


# Task-like phrasings; {c} colour, {k} kind, {K} plural kind, {b} background kind.
COLOUR_KIND_TEMPLATES = (
    "{c} {k}",
    "the {c} {k}",
    "a {c} {k}",
    "get the {c} {k}",
    "pick up the {c} {k}",
    "grab the {c} {k}",
    "find the {c} {k}",
    "get the {c} {K}",
)
KIND_TEMPLATES = ("{k}", "the {k}", "get the {k}", "pick up the {k}", "{K}", "all the {K}", "get all the {K}")
COLOUR_TEMPLATES = (
    "{c} things",
    "all the {c} things",
    "move all the {c} things",
    "{c} objects",
    "something {c}",
)
BACKGROUND_TEMPLATES = ("{b}", "the {b}", "a {b}")
# Phrasings that name an object by its label ({l}); the tasks' own form comes from
# eval.synthetic.tasks.label_task_text ("get"/"pick up" by kind).
LABEL_TEMPLATES = (
    "{c} {k} with the {l} label",
    "the {c} {k} with the {l} label",
    "get the {c} {k} with the {l} label",
    "pick up the {c} {k} with the {l} label",
    "{c} {k} with a {l} label",
)


def captions_for(colour: str | None, kind: str, label: str | None = None) -> list[Caption]:
    """Every phrasing that rightly describes an instance (an object, or a background kind);
    `label`: the colour of the label it shows, which adds the phrasings that name the label."""
    if label is not None and (kind not in LABELLED_KINDS or label == colour or label not in COLOURS):
        raise ValueError(f"a {colour} {kind} cannot show a {label} label")
    if kind in BACKGROUND_KINDS:
        return [Caption(t.format(b=kind), None, kind) for t in BACKGROUND_TEMPLATES]
    if colour is None:
        raise ValueError(f"object kind {kind!r} needs a colour")
    k, big_k = kind, plural(kind)
    out = [Caption(t.format(c=colour, k=k, K=big_k), colour, kind) for t in COLOUR_KIND_TEMPLATES]
    out += [Caption(t.format(k=k, K=big_k), None, kind) for t in KIND_TEMPLATES]
    out += [Caption(t.format(c=colour), colour, None) for t in COLOUR_TEMPLATES]
    if label is not None:
        out += [Caption(t.format(c=colour, k=k, l=label), colour, kind, label) for t in LABEL_TEMPLATES]
    return out


def label_colours(colour: str) -> list[str]:
    """The colours a label on an object of `colour` may have (any other vocabulary colour)."""
    return [c for c in COLOURS if c != colour]


def all_words() -> list[str]:
    """Every word of every phrasing of the vocabulary, sorted (the tiny CLIP's word list)."""
    texts = [c.text for k in BACKGROUND_KINDS for c in captions_for(None, k)]
    texts += [c.text for col in COLOURS for k in KINDS for c in captions_for(col, k)]
    texts += [t.format(c=col, k=k, l=col) for t in LABEL_TEMPLATES for col in COLOURS for k in LABELLED_KINDS]
    return sorted({w for t in texts for w in t.lower().split()})
