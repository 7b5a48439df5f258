"""The content keys of a job's caches, computed in one place from the stage table.

A key hashes exactly what its `CacheSpec` declares (`stage_table`): the perception key the
frame's image and the models; the visibility key that key, the splat, the camera and the
parameters the spec lists; the alignment key the splat with its colours, every camera, the
photos the check renders against, its parameters and its code. Digests are memoised per frame,
since a stage asks for every frame's key more than once (recording cache use, then reading).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from typing import Any

from bayesian_fields_core.checks.alignment import code_fingerprint
from bayesian_fields_core.checks.alignment_reports import spread_indices
from bayesian_fields_core.job.content_keys import (
    alignment_input_digest,
    arrays_digest,
    perception_input_digest,
    splat_digest,
    visibility_input_digest,
)
from bayesian_fields_core.job.stage_table import (
    ALIGNMENT_CACHE,
    PERCEPTION_CACHE,
    VISIBILITY_CACHE,
    cache_parameters,
)
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.scale import SceneLengths
from bayesian_fields_core.scene.types import Scene


def short_hash(obj: Any) -> str:
    """16 hex digits of the SHA-256 of a JSON-able description (sorted keys)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


class CacheKeys:
    """Cache keys of one job: `cache_root` + folder + models fingerprint + content digest."""

    def __init__(
        self,
        scene: Callable[[], Scene],
        params: PipelineParams,
        models_fingerprint: str,
        cache_root: str,
        *,
        lengths: Callable[[], SceneLengths] | None = None,
    ) -> None:
        self._scene = scene
        self._lengths = lengths
        self._params = params
        self.cache_root = cache_root
        self.models_fingerprint = short_hash({"models": models_fingerprint})
        self._perception: dict[int, str] = {}
        self._visibility: dict[int, str] = {}
        self._splat: str | None = None

    @property
    def perception_prefix(self) -> str:
        return f"{self.cache_root}{PERCEPTION_CACHE.folder}{self.models_fingerprint}/"

    @property
    def visibility_prefix(self) -> str:
        return f"{self.cache_root}{VISIBILITY_CACHE.folder}{self.models_fingerprint}/"

    def perception_digest(self, index: int) -> str:
        digest = self._perception.get(index)
        if digest is None:
            digest = self._perception[index] = perception_input_digest(self._scene().frames[index])
        return digest

    def perception_key(self, index: int) -> str:
        """Frame `index`'s masks and embeddings: its image content + the models."""
        return f"{self.perception_prefix}{self.perception_digest(index)}.npz"

    def visibility_key(self, index: int) -> str:
        """Frame `index`'s associations: its perception key, the splat, its camera and the
        parameters `VISIBILITY_CACHE.params` names."""
        digest = self._visibility.get(index)
        if digest is None:
            digest = self._visibility[index] = visibility_input_digest(
                self.perception_key(index),
                self.splat_digest(),
                self._scene().frames[index],
                self._visibility_parameters(),
            )
        return f"{self.visibility_prefix}{digest}.npz"

    def _visibility_parameters(self) -> dict[str, Any]:
        """The declared parameters plus the scene scale they are fractions of: the scale depends
        on every frame's camera (not only the keyed one's), so adding a frame that changes it
        must miss the cache."""
        values = cache_parameters(VISIBILITY_CACHE, self._params)
        if self._lengths is not None:
            values["resolved_scene_scale"] = repr(float(self._lengths().scale))
        return values

    @property
    def alignment_prefix(self) -> str:
        return f"{self.cache_root}{ALIGNMENT_CACHE.folder}"

    def alignment_key(self) -> str:
        """The alignment check's report: what `ALIGNMENT_CACHE` declares. The image digests are
        the perception keys' (memoised), so a warm run hashes no photo twice."""
        scene = self._scene()
        rendered = spread_indices(len(scene.frames), self._params.alignment_frames)
        digest = alignment_input_digest(
            self.splat_digest(),
            arrays_digest(scene.gaussians.sh),
            scene.frames,
            [self.perception_digest(i) for i in rendered],
            cache_parameters(ALIGNMENT_CACHE, self._params),
            code_fingerprint(),
        )
        return f"{self.alignment_prefix}{digest}.json"

    def splat_digest(self) -> str:
        """Content digest of the Gaussians as loaded (computed once)."""
        if self._splat is None:
            self._splat = splat_digest(self._scene().gaussians)
        return self._splat
