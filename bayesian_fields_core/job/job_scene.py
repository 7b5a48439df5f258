"""What a job's scene is: the loaded scene, its lengths, the frames the job reads, the content
keys of its caches and its alignment check, each computed once, when first asked for.

Nothing is loaded when a `JobScene` is made: a worker whose stage is already finished skips it
without fetching the scene, and a job whose frames are all cached never hashes a splat it does not
need. Where the scene comes from is its `SceneSource`, which also says where that is (`origin`),
for the result's provenance and the cache index.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

from bayesian_fields_core.checks.alignment import assess_alignment
from bayesian_fields_core.checks.alignment_reports import AlignmentReport
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.alignment_cache import cached_alignment
from bayesian_fields_core.job.cache_index import record_use
from bayesian_fields_core.job.cache_keys import CacheKeys, short_hash
from bayesian_fields_core.job.scene_source import SceneOrigin, SceneSource
from bayesian_fields_core.job.spec import JobSpec
from bayesian_fields_core.scene.loader import load_scene
from bayesian_fields_core.scene.scale import SceneLengths, scene_lengths
from bayesian_fields_core.scene.types import Frame, Scene

SelectedFrames = tuple[tuple[int, Frame], ...]
"""(capture index, frame) pairs, in capture order."""


class JobScene:
    """The scene of one job (`spec`), read from `source`, with what is computed from it.

    models_fingerprint / profile_name: the job's models (`Models.fingerprint`, `.profile_name`):
    the fingerprint enters the perception and visibility keys, both name the cache index entry.
    allow_source_path: let the loader follow a 3DGS cfg_args `source_path` outside the scene
    folder (the CLI sets it; the service never does: a job reads only its upload).
    splat_transform: a splat -> camera transform file overriding the folder's (CLI
    `--splat-transform`); None = what the folder holds.
    """

    def __init__(
        self,
        spec: JobSpec,
        source: SceneSource,
        *,
        models_fingerprint: str,
        profile_name: str,
        allow_source_path: bool = False,
        splat_transform: Path | None = None,
    ) -> None:
        self._spec = spec
        self.source = source
        self.models_fingerprint = models_fingerprint
        self.profile_name = profile_name
        self.allow_source_path = allow_source_path
        self.splat_transform = splat_transform
        self._alignment: tuple[AlignmentReport | None] | None = None

    @property
    def origin(self) -> SceneOrigin:
        """Where the scene comes from (a local folder or a store prefix)."""
        return self.source.origin()

    @cached_property
    def loaded(self) -> Scene:
        """The scene, loaded from the source's folder (fetched into a local folder if need be)."""
        return load_scene(
            self.source.folder(),
            allow_source_path=self.allow_source_path,
            splat_transform=self.splat_transform,
        )

    @cached_property
    def lengths(self) -> SceneLengths:
        """Every length of this job in scene units: the parameters' fractions of the scene scale
        (measured once per scene), or their absolute overrides (`scene/scale.py`)."""
        return scene_lengths(self._spec.params, lambda: self.loaded.scale())

    @cached_property
    def selected_frames(self) -> SelectedFrames:
        """(capture index, frame) pairs after stride and max_frames, in capture order."""
        params = self._spec.params
        frames = list(enumerate(self.loaded.frames))[:: params.frame_stride]
        if params.max_frames is not None:
            frames = frames[: params.max_frames]
        if not frames:
            raise InputError("the scene has no frames", source="cameras")
        return tuple(frames)

    @cached_property
    def keys(self) -> CacheKeys:
        """This job's cache keys (memoised digests per frame; nothing is hashed until asked)."""
        return CacheKeys(
            lambda: self.loaded,
            self._spec.params,
            self.models_fingerprint,
            self._spec.cache_prefix,
            lengths=lambda: self.lengths,
        )

    def alignment(self, device: str) -> AlignmentReport | None:
        """The scene's alignment check (geometric + rendered on `device`, `checks/alignment.py`),
        run once per job and cached across jobs on its inputs' content (`alignment_cache`): the
        CLI calls it to print the score before perception, the perceive stage calls it again for
        free. Raises InputError (one line) when the splat does not line up; returns the
        `AlignmentReport`, or None when `params.alignment_check` is off."""
        if self._alignment is None:
            report: AlignmentReport | None = None
            params = self._spec.params
            if params.alignment_check:
                key = self.keys.alignment_key()
                self.record_cache_use("alignment", [key])  # before computing: a prune keeps it
                found = cached_alignment(
                    self._spec.cache_store, key, lambda: assess_alignment(self.loaded, params, device=device)
                )
                report = found.raise_if_failed()
            self._alignment = (report,)
        return self._alignment[0]

    def record_cache_use(self, stage: str, keys: list[str]) -> None:
        """Note in the cache index that this scene + profile uses `keys` (for `bfields cache`)."""
        frames = self.selected_frames
        # The scene by its images' content alone (the same scene under two profiles: one id).
        scene_id = short_hash([self.keys.perception_digest(i) for i, _ in frames])
        record_use(
            self._spec.cache_store,
            self._spec.cache_prefix,
            short_hash({"scene": scene_id, "models": self.keys.models_fingerprint}),
            stage=stage,
            keys=keys,
            about={
                "scene": self.origin.label(),
                "scene_id": scene_id,
                "profile": self.profile_name,
                "fingerprint": self.keys.models_fingerprint,
                "frames": len(frames),
            },
        )
