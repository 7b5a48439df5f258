"""Where a job's scene folder comes from: a `SceneSource` hands the context a local folder.

The loader reads a folder on disk. The CLI has one already (`LocalFolder`); a job whose scene
lives in a store gets it downloaded (`StoreDownload`); the worker lends a copy from its host's
shared scene cache (`bayesian_fields_service.worker.scene_cache`), one more implementation of
the same protocol injected into the context instead of overriding it.
"""

from __future__ import annotations

import hashlib
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore, Store


class SceneSource(Protocol):
    """Gives the scene's input folder (images, cameras, splat) as a local path."""

    def folder(self) -> Path:
        """The folder `scene.loader.load_scene` reads; called once per context."""
        ...


@dataclass(frozen=True)
class LocalFolder:
    """A scene folder already on this machine (the CLI, the evaluation, the benches)."""

    path: Path

    def folder(self) -> Path:
        return Path(self.path)


@dataclass(frozen=True)
class StoreDownload:
    """The scene's ``<prefix>input/`` files in `store`, downloaded below `work_dir` (files already
    there with the right size are kept, so a second stage of the same job downloads nothing)."""

    store: Store
    prefix: str
    work_dir: Path | None = None

    def folder(self) -> Path:
        store = self.store
        if isinstance(store, LocalStore):
            local = store.root / self.prefix / "input"
            if local.is_dir():
                return local
        prefix = self.prefix + "input/"
        keys = store.list(prefix)
        if not keys:
            raise InputError(f"no scene files under {prefix!r}", source="scene")
        base = self.work_dir or Path(tempfile.gettempdir()) / "bfields-scenes"
        where = json.dumps({"prefix": self.prefix, "store": repr(store)}, sort_keys=True)
        target = base / hashlib.sha256(where.encode()).hexdigest()[:16] / "input"
        for key in keys:
            dest = target / key[len(prefix) :]
            if dest.is_file() and dest.stat().st_size == store.size(key):
                continue
            store.get_file(key, dest)
        return target
