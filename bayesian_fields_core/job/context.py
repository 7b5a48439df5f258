"""What a stage needs to run: where artifacts live, the scene, the models and the callbacks.

The CLI builds one of these around local folders; a Celery worker builds one around the S3
bucket. The stages see only this object, which is how both run the very same code.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bayesian_fields_core.errors import CancelledError, InputError
from bayesian_fields_core.job.cache_keys import CacheKeys, short_hash
from bayesian_fields_core.job.flight import Flight, NoFlight
from bayesian_fields_core.job.scene_source import LocalFolder, SceneSource, StoreDownload
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.scene.scale import SceneLengths, scene_lengths
from bayesian_fields_core.scene.types import Frame, Scene

if TYPE_CHECKING:
    from bayesian_fields_core.calibration.model import Calibration
    from bayesian_fields_core.checks.alignment_reports import AlignmentReport
    from bayesian_fields_core.perception.encoder import Encoder
    from bayesian_fields_core.perception.profiles import ModelProfile
    from bayesian_fields_core.perception.segmenter import Segmenter

log = logging.getLogger(__name__)

ProgressFn = Callable[[str, float], None]
CancelFn = Callable[[], bool]


def _no_progress(stage: str, fraction: float) -> None:
    return None


def _never_cancel() -> bool:
    return False


class Models:
    """The perception models of a model profile, built on first use, plus their calibration.

    `fingerprint` identifies segmenter + encoder + their parameters without loading anything; it
    keys the perception cache so a cached embedding is only reused with the exact models that
    produced it. Loading is lazy so a CPU worker running only `cluster` never loads CLIP. Loading
    is logged (INFO "loading models: ...", which the CLI prints; DEBUG the seconds each took), and
    `load_seconds` keeps those seconds by role.
    """

    def __init__(self, profile: ModelProfile, *, device: str | None = None) -> None:
        from bayesian_fields_core.perception import profiles as registry

        self._registry = registry
        self.profile = profile
        self.device = device
        self.fingerprint: str = registry.profile_fingerprint(profile)
        self.profile_name: str = profile.name
        self._built: dict[str, Any] = {}
        self.load_seconds: dict[str, float] = {}
        self._calibration: Calibration | None = None
        self._calibration_loaded = False
        #: Applied to the encoder when it is built (a worker's test-only call counter wraps it).
        self.encoder_wrapper: Callable[[Encoder], Encoder] | None = None

    def describe(self, role: str) -> str:
        """One model in words for the log: ``encoder hf_clip (tiny-clip, cpu)``."""
        cfg = self.profile.segmenter if role == "segmenter" else self.profile.encoder
        where = cfg.describe()
        device = self.device or getattr(cfg, "device", None)
        return f"{role} {cfg.kind}" + (
            f" ({', '.join(x for x in (where, device) if x)})" if where or device else ""
        )

    def load(self, *roles: str) -> None:
        """Build the named models ("segmenter", "encoder") not built yet, saying so in one line."""
        todo = [r for r in roles if r not in self._built]
        if not todo:
            return
        log.info("loading models: %s", ", ".join(self.describe(r) for r in todo))
        for role in todo:
            start = time.perf_counter()
            if role == "segmenter":
                self._built[role] = self._registry.build_segmenter(self.profile.segmenter, device=self.device)
            else:
                encoder = self._registry.build_encoder(self.profile.encoder, device=self.device)
                self._built[role] = encoder if self.encoder_wrapper is None else self.encoder_wrapper(encoder)
            self.load_seconds[role] = time.perf_counter() - start
            log.debug("%s loaded in %.2f s", self.describe(role), self.load_seconds[role])

    @property
    def segmenter(self) -> Segmenter:
        self.load("segmenter")
        return self._built["segmenter"]

    @property
    def encoder(self) -> Encoder:
        self.load("encoder")
        return self._built["encoder"]

    @property
    def render_device(self) -> str:
        """Where depth is rendered when the job names no device: the models' device if one was
        forced (a worker's), else the CPU."""
        return self.device or "cpu"

    @property
    def calibration(self) -> Calibration | None:
        """The profile's score calibration (checked against the encoder), or None when it has none."""
        if not self._calibration_loaded:
            # A calibration file made for another encoder is refused: its mu0/mu1/s would be wrong.
            self._calibration = self._registry.load_profile_calibration(
                self.profile, model_id=self._registry.encoder_model_id(self.profile.encoder)
            )
            self._calibration_loaded = True
        return self._calibration

    @property
    def model_ids(self) -> dict[str, str]:
        cal = self.calibration
        return {
            "profile": self.profile_name,
            "segmenter": self.profile.segmenter.kind,
            "encoder": self._registry.encoder_model_id(self.profile.encoder),
            "calibration": getattr(cal, "model_id", "") or "",
            "fingerprint": self.fingerprint,
        }


@dataclass
class JobContext:
    """Everything a stage reads: stores, key prefixes, tasks, parameters, models, callbacks.

    store / job_prefix: where this job's artifacts go (``stages/<name>.json`` marks a finished
    stage, ``result/`` holds the result).
    scene_store / scene_prefix: where the scene's input files (``input/``) and its
    task-independent caches live; defaults to `store`.
    cache_prefix: where in `scene_store` the caches live (``perception/``, ``visibility/``,
    ``index/`` below it); default ``<scene_prefix>cache/``. Cache keys are content digests, so one
    cache can serve every scene (the CLI's ``~/.cache/bfields``).
    scene_dir: a local folder holding the scene; when None the input is fetched from the store.
    scene_source: where the scene folder comes from, injected (`scene_source.SceneSource`; the
    worker's shared scene cache is one); None = `scene_dir`, else a download from `scene_store`.
    allow_source_path: let the loader follow a 3DGS cfg_args `source_path` outside the scene
    folder (the CLI sets it; the service never does: a job reads only its upload).
    splat_transform: a splat -> camera transform file overriding the folder's (CLI
    `--splat-transform`); None = what the folder holds.
    flight: how concurrent jobs on one scene share the filling of its caches (`flight.Flight`;
    the CLI's `NoFlight`, a worker's Redis lock).
    """

    store: Store
    job_prefix: str
    tasks: list[str]
    params: PipelineParams
    models: Models
    scene_prefix: str = "scene/"
    scene_store: Store | None = None
    scene_dir: Path | None = None
    work_dir: Path | None = None
    allow_source_path: bool = False
    splat_transform: Path | None = None
    progress: ProgressFn = _no_progress
    should_cancel: CancelFn = _never_cancel
    cache_prefix: str | None = None
    _scene: Scene | None = field(default=None, repr=False)
    _alignment: AlignmentReport | None = field(default=None, repr=False)
    _alignment_done: bool = field(default=False, repr=False)
    scene_source: SceneSource | None = None
    flight: Flight = field(default_factory=NoFlight)
    _keys: CacheKeys | None = field(default=None, repr=False)
    _lengths: SceneLengths | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.scene_store is None:
            self.scene_store = self.store
        if self.job_prefix and not self.job_prefix.endswith("/"):
            self.job_prefix += "/"
        if self.scene_prefix and not self.scene_prefix.endswith("/"):
            self.scene_prefix += "/"
        if not self.tasks:
            raise InputError("the task list is empty", source="tasks")
        if len(set(self.tasks)) != len(self.tasks):
            raise InputError("the task list has duplicates", source="tasks")

    # ---- keys (computed by `cache_keys` from the stage table) ----------------------------
    def job_key(self, name: str) -> str:
        return self.job_prefix + name

    @property
    def cache_root(self) -> str:
        """Prefix of the task-independent caches in `scene_store` (see `cache_index`)."""
        return self.scene_prefix + "cache/" if self.cache_prefix is None else self.cache_prefix

    @property
    def keys(self) -> CacheKeys:
        """This job's cache keys (memoised digests per frame)."""
        if self._keys is None:
            self._keys = CacheKeys(
                self.scene, self.params, self.models.fingerprint, self.cache_root, lengths=self.lengths
            )
        return self._keys

    @property
    def perception_prefix(self) -> str:
        """Cached perception frames of this job's models (any scene): ``<digest>.npz`` below."""
        return self.keys.perception_prefix

    @property
    def visibility_prefix(self) -> str:
        """Cached mask-to-Gaussian associations made from this job's models' masks."""
        return self.keys.visibility_prefix

    @property
    def perception_fingerprint(self) -> str:
        """Segmenter + encoder identities and their parameters (the profile's model part)."""
        return self.keys.models_fingerprint

    def perception_key(self, index: int) -> str:
        return self.keys.perception_key(index)

    def visibility_key(self, index: int) -> str:
        return self.keys.visibility_key(index)

    def splat_digest(self) -> str:
        return self.keys.splat_digest()

    def record_cache_use(self, stage: str, keys: list[str]) -> None:
        """Note in the cache index that this scene + profile uses `keys` (for `bfields cache`)."""
        from bayesian_fields_core.job.cache_index import record_use

        frames = self.selected_frames()
        # The scene by its images' content alone (the same scene under two profiles: one id).
        scene_id = short_hash([self.keys.perception_digest(i) for i, _ in frames])
        root = self.scene_dir
        record_use(
            self.scene_store,  # type: ignore[arg-type]
            self.cache_root,
            short_hash({"scene": scene_id, "models": self.perception_fingerprint}),
            stage=stage,
            keys=keys,
            about={
                "scene": str(Path(root).resolve()) if root is not None else self.scene_prefix,
                "scene_id": scene_id,
                "profile": self.models.profile_name,
                "fingerprint": self.perception_fingerprint,
                "frames": len(frames),
            },
        )

    # ---- scene ---------------------------------------------------------------------------
    def scene(self) -> Scene:
        """Load (once) the scene, fetching it from the store into work_dir when not local."""
        if self._scene is None:
            from bayesian_fields_core.scene.loader import load_scene

            folder = self.source().folder()
            self._scene = load_scene(
                folder, allow_source_path=self.allow_source_path, splat_transform=self.splat_transform
            )
        return self._scene

    def lengths(self) -> SceneLengths:
        """Every length of this job in scene units: the parameters' fractions of the scene scale
        (measured once per scene), or their absolute overrides (`scene/scale.py`)."""
        if self._lengths is None:
            self._lengths = scene_lengths(self.params, lambda: self.scene().scale())
        return self._lengths

    def alignment(self) -> AlignmentReport | None:
        """The scene's alignment check (geometric + rendered, `checks/alignment.py`), run once per
        context and cached across jobs on its inputs' content (`alignment_cache`): the CLI calls
        it to print the score before perception, the perceive stage calls it again for free.
        Raises InputError (one line) when the splat does not line up; returns the
        `AlignmentReport`, or None when `params.alignment_check` is off."""
        if not self._alignment_done:
            if self.params.alignment_check:
                from bayesian_fields_core.checks.alignment import assess_alignment
                from bayesian_fields_core.job.alignment_cache import cached_alignment

                key = self.keys.alignment_key()
                self.record_cache_use("alignment", [key])  # before computing: a prune keeps it
                device = self.params.device or self.models.render_device
                store = self.scene_store
                assert store is not None
                report = cached_alignment(
                    store, key, lambda: assess_alignment(self.scene(), self.params, device=device)
                )
                self._alignment = report.raise_if_failed()
            self._alignment_done = True
        return self._alignment

    def selected_frames(self) -> list[tuple[int, Frame]]:
        """(capture index, frame) pairs after stride and max_frames, in capture order."""
        frames = list(enumerate(self.scene().frames))[:: self.params.frame_stride]
        if self.params.max_frames is not None:
            frames = frames[: self.params.max_frames]
        if not frames:
            raise InputError("the scene has no frames", source="cameras")
        return frames

    def source(self) -> SceneSource:
        """Where the scene folder comes from: the injected source, else `scene_dir`, else a
        download of ``<scene_prefix>input/`` from `scene_store` into `work_dir`."""
        if self.scene_source is not None:
            return self.scene_source
        if self.scene_dir is not None:
            return LocalFolder(self.scene_dir)
        assert self.scene_store is not None
        return StoreDownload(self.scene_store, self.scene_prefix, self.work_dir)

    # ---- callbacks -----------------------------------------------------------------------
    def check_cancel(self) -> None:
        if self.should_cancel():
            raise CancelledError("job cancelled")
