"""The cache's index: which scene and profile use which cached frames (and alignment verdicts), and
when they were last used.

Cached frames are keyed on content, so a frame file does not say which scene it came from, and
two scenes sharing images share entries. Each stage therefore records, before it computes, one
small JSON per (scene content, model profile) under ``<cache prefix>index/``: the keys it reads or
writes, the folder the scene was last run from (for people; it plays no part in any key), the
profile's name and fingerprint, and the time of last use. `bfields cache ls` lists these
entries; `prune` drops whole entries least recently used first and then deletes every cached
frame that no remaining entry references (orphans of crashed or older-layout runs included).
Written before computing, an entry protects a running job's frames from a concurrent prune.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from bayesian_fields_core.job.artifacts import ALIGNMENT_CACHE_DIR, PERCEPTION_CACHE_DIR, VISIBILITY_CACHE_DIR
from bayesian_fields_core.job.store import ArtifactNotFound, Store, get_json, put_json

INDEX_DIR = "index/"
DATA_DIRS = (
    PERCEPTION_CACHE_DIR,
    VISIBILITY_CACHE_DIR,
    ALIGNMENT_CACHE_DIR,
    "scenes/",
)  # scenes/: the pre-content-key layout


@dataclass
class CacheEntry:
    """One scene + profile in the cache: its keys, their total size and when it was last used."""

    key: str
    scene: str
    scene_id: str
    profile: str
    fingerprint: str
    last_used: float
    frames: int
    keys: list[str] = field(default_factory=list)
    size: int = 0


def record_use(
    store: Store,
    cache_prefix: str,
    entry_id: str,
    *,
    stage: str,
    keys: list[str],
    about: dict[str, Any],
) -> None:
    """Merge `keys` (cache keys relative to the store) into the entry for this scene + profile and
    stamp it as used now. `about`: scene, scene_id, profile, fingerprint, frames (for `ls`)."""
    key = f"{cache_prefix}{INDEX_DIR}{entry_id}.json"
    try:
        old = get_json(store, key)
    except (ArtifactNotFound, ValueError):
        old = {}
    stages = dict(old.get("stages", {}))
    stages[stage] = sorted(set(stages.get(stage, [])) | set(keys))
    put_json(store, key, {**old, **about, "stages": stages, "last_used": time.time()})


def list_entries(store: Store, cache_prefix: str = "") -> list[CacheEntry]:
    """Every index entry, most recently used first, with the summed size of its existing keys."""
    entries = []
    for key in store.list(cache_prefix + INDEX_DIR):
        if not key.endswith(".json"):
            continue
        try:
            raw = get_json(store, key)
        except (ArtifactNotFound, ValueError):
            continue
        keys = sorted({k for ks in raw.get("stages", {}).values() for k in ks})
        size = 0
        present = []
        for k in keys:
            try:
                size += store.size(k)
                present.append(k)
            except ArtifactNotFound:
                continue
        entries.append(
            CacheEntry(
                key=key,
                scene=str(raw.get("scene", "?")),
                scene_id=str(raw.get("scene_id", "?")),
                profile=str(raw.get("profile", "?")),
                fingerprint=str(raw.get("fingerprint", "?")),
                last_used=float(raw.get("last_used", 0.0)),
                frames=int(raw.get("frames", 0)),
                keys=present,
                size=size,
            )
        )
    return sorted(entries, key=lambda e: e.last_used, reverse=True)


def data_keys(store: Store, cache_prefix: str = "") -> list[str]:
    """Every cached artifact (not the index) under the prefix."""
    return [k for d in DATA_DIRS for k in store.list(cache_prefix + d)]


@dataclass
class PruneReport:
    entries_removed: int
    files_removed: int
    bytes_freed: int
    bytes_left: int


def prune(
    store: Store,
    cache_prefix: str = "",
    *,
    older_than_s: float | None = None,
    max_size: int | None = None,
    now: float | None = None,
) -> PruneReport:
    """Drop entries unused for longer than `older_than_s`, then the least recently used ones until
    the frames the rest reference fit in `max_size` bytes; delete every unreferenced frame."""
    now = time.time() if now is None else now
    kept = list_entries(store, cache_prefix)  # most recent first
    dropped = []
    if older_than_s is not None:
        dropped = [e for e in kept if now - e.last_used > older_than_s]
        kept = [e for e in kept if now - e.last_used <= older_than_s]
    sizes: dict[str, int] = {}
    for k in data_keys(store, cache_prefix):
        sizes[k] = store.size(k)

    def referenced_size(entries: list[CacheEntry]) -> int:
        return sum(sizes.get(k, 0) for k in {k for e in entries for k in e.keys})

    if max_size is not None:
        while kept and referenced_size(kept) > max_size:
            dropped.append(kept.pop())  # the least recently used
    for e in dropped:
        store.delete(e.key)
    referenced = {k for e in kept for k in e.keys}
    removed = [k for k in sizes if k not in referenced]
    for k in removed:
        store.delete(k)
    freed = sum(sizes[k] for k in removed)
    return PruneReport(
        entries_removed=len(dropped),
        files_removed=len(removed),
        bytes_freed=freed,
        bytes_left=sum(sizes.values()) - freed,
    )
