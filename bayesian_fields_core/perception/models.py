"""The perception models a job runs with: a model profile's segmenter and encoder, built lazily.

The CLI, the workers, the evaluation and the benches all get theirs from `load_models`; a job's
`Runner` (`job/runner.py`) carries them to the stages. They live here, beside the profiles they
are built from, so that a module that only needs models (the evaluation's regimes, a bench) does
not reach into the job runtime for them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bayesian_fields_core.calibration.model import Calibration
    from bayesian_fields_core.perception.encoder import Encoder
    from bayesian_fields_core.perception.profiles import ModelProfile
    from bayesian_fields_core.perception.segmenter import Segmenter

log = logging.getLogger(__name__)


class Models:
    """The perception models of a model profile, built on first use, plus their calibration.

    `fingerprint` identifies segmenter + encoder + their parameters without loading anything; it
    keys the perception cache so a cached embedding is only reused with the exact models that
    produced it. Loading is lazy so a CPU worker running only `cluster` never loads CLIP. Loading
    is logged (INFO "loading models: ...", which the CLI prints; DEBUG the seconds each took), and
    `load_seconds` keeps those seconds by role. `device`, when set, overrides the profile's
    per-model devices (a worker's BFIELDS_WORKER_DEVICE, the CLI's ``--param device``); the
    job's `Runner.render_device` falls back to it.
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
        #: Applied to the encoder when it is built (a service worker passes it through its hooks).
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


def load_models(profile: Any = None, *, device: str | None = None) -> Models:
    """Models of a model profile (path, dict or `ModelProfile`); built lazily on first use.

    None selects the bundled default profile (classical segmenter + the project's tiny CLIP).
    `device` overrides the profile's per-model devices; None keeps them.
    """
    from bayesian_fields_core.perception import profiles as registry

    if profile is None:
        prof = registry.default_profile()
    elif isinstance(profile, str | Path | dict):
        prof = registry.load_profile(profile)
    else:
        prof = profile
    return Models(prof, device=device)
