"""Compare the objects of two runs of one scene: which are the same, split, merged, changed, new
or gone (`bfields compare`).

Ids are per run (rows of each result's tables), so two runs are matched by their Gaussians. For
an object `b` of run B and an object `a` of run A, "most of `a` lies in `b`" means more than
half of `a`'s Gaussians belong to `b` (a strict majority, so each object has at most one such
partner). Each object of B gets the first status that applies:

  same     an object of A holds exactly the same Gaussians (then the content keys are equal)
  merged   two or more objects of A each have most of their Gaussians in b
  changed  b and an object a of A each hold most of the other's Gaussians: the same object with
           some Gaussians gained or lost
  split    most of b lies in an object a of A, most of a does not lie in b, and two or more
           objects of B each have most of their Gaussians in a (a was divided; b is a part)
  changed  (also) one object of A is linked to b by a majority one way only and none of the
           above applies: most of b lies in it, or most of it lies in b
  new      no object of A holds most of b, and none has most of its Gaussians in b

and every object of A that no object of B is linked to by a majority either way is `gone`.
Objects without Gaussians (every one removed as a floater) are left out of both sides. The
related A objects are listed with each B object (for `same`, `changed`, `split` the one, for
`merged` all of them). Only the two id maps are read: numpy and the standard library.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.results.format import Result
from bayesian_fields_core.results.keys import object_members

STATUSES = ("same", "changed", "split", "merged", "new", "gone")


@dataclass
class ObjectMatch:
    """One row of a comparison: an object of B (or, for 'gone', of A) and how it relates."""

    status: str
    object_b: int | None
    key_b: str | None
    gaussians_b: int
    objects_a: list[int] = field(default_factory=list)
    keys_a: list[str] = field(default_factory=list)
    shared: int = 0
    """Gaussians the object shares with the related A objects, together."""

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "object_b": self.object_b,
            "key_b": self.key_b,
            "gaussians_b": self.gaussians_b,
            "objects_a": self.objects_a,
            "keys_a": self.keys_a,
            "shared_gaussians": self.shared,
        }


def _shared(ids_a: np.ndarray, ids_b: np.ndarray) -> dict[tuple[int, int], int]:
    """{(object of A, object of B): Gaussians they share}, for every pair sharing any."""
    both = (ids_a >= 0) & (ids_b >= 0)
    pairs, counts = np.unique(np.stack([ids_a[both], ids_b[both]]), axis=1, return_counts=True)
    return {(a, b): n for (a, b), n in zip(pairs.T.tolist(), counts.tolist(), strict=True)}


def _majority_homes(
    shared: dict[tuple[int, int], int], size_a: np.ndarray, size_b: np.ndarray
) -> tuple[dict[int, int], dict[int, int]]:
    """({object of B: the object of A holding more than half of it}, the same from A to B)."""
    home_in_a, home_in_b = {}, {}
    for (a, b), n in shared.items():
        if 2 * n > size_b[b]:
            home_in_a[b] = a
        if 2 * n > size_a[a]:
            home_in_b[a] = b
    return home_in_a, home_in_b


def compare_results(a: Result, b: Result) -> list[ObjectMatch]:
    """The rows of the comparison of B against A (module docstring): every non-empty object of
    B in id order, then the `gone` objects of A."""
    if a.num_gaussians != b.num_gaussians:
        raise InputError(
            f"the results cover {a.num_gaussians} and {b.num_gaussians} Gaussians: not runs of one splat; "
            "compare two results of the same scene"
        )
    if a.splat_digest and b.splat_digest and a.splat_digest != b.splat_digest:
        raise InputError(
            "the results were computed from different splats (splat_digest differs); compare two results "
            "of the same scene"
        )
    ids_a, ids_b = np.asarray(a.object_ids), np.asarray(b.object_ids)
    size_a = np.bincount(ids_a[ids_a >= 0], minlength=a.num_objects)
    size_b = np.bincount(ids_b[ids_b >= 0], minlength=b.num_objects)
    keys_a, keys_b = a.content_keys(), b.content_keys()
    shared = _shared(ids_a, ids_b)
    home_in_a, home_in_b = _majority_homes(shared, size_a, size_b)
    into_b: dict[int, list[int]] = {}
    for obj_a, obj_b in home_in_b.items():
        into_b.setdefault(obj_b, []).append(obj_a)
    into_a: dict[int, list[int]] = {}
    for obj_b, obj_a in home_in_a.items():
        into_a.setdefault(obj_a, []).append(obj_b)
    by_members = _identical(a, b)
    rows: list[ObjectMatch] = []
    for obj_b in np.flatnonzero(size_b).tolist():
        status, related = _status(obj_b, by_members, into_b, into_a, home_in_a)
        rows.append(
            ObjectMatch(
                status=status,
                object_b=obj_b,
                key_b=keys_b[obj_b],
                gaussians_b=int(size_b[obj_b]),
                objects_a=related,
                keys_a=[keys_a[o] for o in related],
                shared=sum(shared.get((o, obj_b), 0) for o in related),
            )
        )
    linked = set(home_in_b) | set(home_in_a.values())
    for obj_a in np.flatnonzero(size_a).tolist():
        if obj_a not in linked:
            rows.append(ObjectMatch("gone", None, None, 0, [obj_a], [keys_a[obj_a]], 0))
    return rows


def _identical(a: Result, b: Result) -> dict[int, int]:
    """{object of B: the object of A with exactly its Gaussians}, found through the content
    keys computed without the splat digest (so results before format 1.5 compare too)."""
    members_a = object_members(a.object_ids, a.num_objects)
    members_b = object_members(b.object_ids, b.num_objects)
    index = {m.tobytes(): o for o, m in enumerate(members_a) if m.size}
    return {o: index[m.tobytes()] for o, m in enumerate(members_b) if m.size and m.tobytes() in index}


def _status(
    obj_b: int,
    identical: dict[int, int],
    into_b: dict[int, list[int]],
    into_a: dict[int, list[int]],
    home_in_a: dict[int, int],
) -> tuple[str, list[int]]:
    """(status, related A objects) of one B object, by the rules of the module docstring."""
    if obj_b in identical:
        return "same", [identical[obj_b]]
    sources = sorted(into_b.get(obj_b, []))
    if len(sources) >= 2:
        return "merged", sources
    home = home_in_a.get(obj_b)
    if home is not None and sources == [home]:
        return "changed", [home]  # each holds most of the other
    if home is not None and len(into_a.get(home, [])) >= 2:
        return "split", [home]
    if home is not None:
        return "changed", [home]
    if sources:
        return "changed", sources
    return "new", []


def status_counts(rows: list[ObjectMatch]) -> dict[str, int]:
    """How many rows have each status (every status listed, zeros included)."""
    counts = dict.fromkeys(STATUSES, 0)
    for row in rows:
        counts[row.status] += 1
    return counts
