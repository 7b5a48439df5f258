"""Where a job's scene folder comes from: a `SceneSource` hands the job's scene a local folder.

The loader reads a folder on disk. The CLI has one already (`LocalFolder`); a job whose scene
lives in a store gets it downloaded (`StoreDownload`); the worker lends a copy from its host's
shared scene cache (`bayesian_fields_service.worker.scene_cache`), one more implementation of
the same protocol given to the job's factory (`job/factories.py`) instead of overriding it.
A source also says where the scene comes from (`SceneOrigin`), which the result's provenance and
the cache index record: nothing downstream has to guess it from which program runs the job.
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


@dataclass(frozen=True)
class SceneOrigin:
    """Where a scene's files come from, as a result (`bfields view`) and the cache index name it:
    a local folder, or the scene's prefix in the job's store (its files under ``<prefix>input/``).
    Exactly one of the two is set."""

    folder: Path | None = None
    prefix: str | None = None

    def __post_init__(self) -> None:
        if (self.folder is None) == (self.prefix is None):
            raise ValueError("a scene origin is a folder or a store prefix, exactly one")
        if self.prefix and not self.prefix.endswith("/"):
            object.__setattr__(self, "prefix", self.prefix + "/")

    def record(self) -> dict[str, str | None]:
        """The result's ``scene`` fields: ``folder`` (absolute) or ``store_prefix`` (its input)."""
        return {
            "folder": None if self.folder is None else str(self.folder.resolve()),
            "store_prefix": None if self.prefix is None else f"{self.prefix}input/",
        }

    def label(self) -> str:
        """The scene in the cache index's ``scene`` field: the absolute folder, else the prefix."""
        return str(self.folder.resolve()) if self.folder is not None else str(self.prefix)


class SceneSource(Protocol):
    """Gives the scene's input folder (images, cameras, splat) as a local path."""

    def folder(self) -> Path:
        """The folder `scene.loader.load_scene` reads; called once per job."""
        ...

    def origin(self) -> SceneOrigin:
        """Where the scene comes from, for provenance (cheap: never fetches anything)."""
        ...


@dataclass(frozen=True)
class LocalFolder:
    """A scene folder already on this machine (the CLI, the evaluation, the benches)."""

    path: Path

    def folder(self) -> Path:
        return Path(self.path)

    def origin(self) -> SceneOrigin:
        return SceneOrigin(folder=Path(self.path))


@dataclass(frozen=True)
class StoreDownload:
    """The scene's ``<prefix>input/`` files in `store`, downloaded below `work_dir` (files already
    there with the right size are kept, so a second stage of the same job downloads nothing)."""

    store: Store
    prefix: str
    work_dir: Path | None = None

    def origin(self) -> SceneOrigin:
        return SceneOrigin(prefix=self.prefix)

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
