"""Object content keys: a name for an object that survives re-runs.

An object's id is its row in the result's tables, so it is only meaningful within one run: the
same mug is object 26 with eight tasks and object 70 with two. Its *key* is derived from what the
object is, its set of Gaussians: BLAKE2b (8-byte digest, 16 hex characters) over the splat's
content digest (`job.content_keys.splat_digest`, recorded as `splat_digest` since format 1.5)
followed by the object's Gaussian indices in increasing order as little-endian int64. So two
runs give an object the same key exactly when it holds the same Gaussians of the same splat, and
keys of different scenes differ. Results older than 1.5 record no splat digest; their keys are
computed with an empty one (comparable among such results only).

Numpy and the standard library only: the light reader computes keys for results that lack them.
"""

from __future__ import annotations

import hashlib

import numpy as np

KEY_BYTES = 8
"""64-bit keys: a collision among the few hundred objects of a scene has odds near 1e-15."""
_PERSON = b"bfields-object"
"""BLAKE2b personalisation: these digests can equal no other digest of the same bytes."""


def object_members(object_ids: np.ndarray, num_objects: int) -> list[np.ndarray]:
    """Per object row, its Gaussian indices in increasing order (-1 = none is left out)."""
    ids = np.asarray(object_ids)
    order = np.argsort(ids, kind="stable")  # stable: indices stay increasing within each object
    counts = np.bincount(ids[ids >= 0], minlength=num_objects)
    start = int(np.count_nonzero(ids < 0))
    bounds = start + np.concatenate([[0], np.cumsum(counts)])
    return [order[bounds[o] : bounds[o + 1]] for o in range(num_objects)]


def object_key(gaussian_indices: np.ndarray, splat_digest: str = "") -> str:
    """The key of the object holding `gaussian_indices` (any order) of the splat `splat_digest`."""
    h = hashlib.blake2b(digest_size=KEY_BYTES, person=_PERSON)
    h.update(splat_digest.encode("ascii") + b"\0")
    h.update(np.sort(np.asarray(gaussian_indices, dtype="<i8")).tobytes())
    return h.hexdigest()


def object_keys(object_ids: np.ndarray, num_objects: int, splat_digest: str = "") -> list[str]:
    """The key of every object row (`object_key` of its Gaussians)."""
    return [object_key(m, splat_digest) for m in object_members(object_ids, num_objects)]
