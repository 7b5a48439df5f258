"""Model profiles: which segmenter, which CLIP encoder and which calibration a run uses.

A profile is a small YAML file the operator writes (models are files they provide; nothing is
downloaded)::

    name: default
    segmenter: {kind: classical, params: {method: felzenszwalb, scale: 300}}
    encoder: {kind: hf_clip, path: ../tiny-clip, params: {resize_mode: shortest_crop}}
    calibration: {path: ../tiny-clip/calibration.json}   # or {mu0: 0.2, mu1: 0.27, s: 0.035}

Each ``kind`` is one typed class in ``perception/kinds.py`` (see ``kind_base``): its
``params`` are checked when the profile is read (an unknown or mistyped key is a one-line
``InputError`` naming the file and the field), and it builds the ``Segmenter`` / ``Encoder``.
Relative model paths (``encoder.path``, a kind's model-file params such as FastSAM's ``weights``,
``calibration.path``) are resolved against the profile file's folder, so a profile travels with
its models. ``profile_fingerprint`` hashes everything that changes the perception output (each
section's identity: kind and set params, model files by content, the encoder's model id, plus the
crop settings) and keys the per-scene perception cache; runtime-only settings (device, threads,
providers, batch size) are left out.
"""

from __future__ import annotations

import hashlib
import json
import os
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    SerializeAsAny,
    ValidationError,
    model_validator,
)

from bayesian_fields_core.calibration.model import Calibration, load_calibration
from bayesian_fields_core.errors import InputError, ModelError
from bayesian_fields_core.perception import kinds as _builtin_kinds  # noqa: F401  (registers them)
from bayesian_fields_core.perception.encoder import Encoder
from bayesian_fields_core.perception.kind_base import (
    ENCODERS,
    SEGMENTERS,
    EncoderConfig,
    SegmenterConfig,
    resolve_path,
)
from bayesian_fields_core.perception.segmenter import Segmenter

# mask_crops defaults used by the perceive stage; part of the fingerprint so a change re-embeds.
CROP_SETTINGS = {"background": "gray", "pad_fraction": 0.1, "square": True}
DEFAULT_PROFILE_ENV = "BFIELDS_DEFAULT_PROFILE"

#: A profile section validated as the class its ``kind`` names (``SerializeAsAny``: dumped whole).
SegmenterSection = Annotated[SerializeAsAny[SegmenterConfig], BeforeValidator(SEGMENTERS.parse)]
EncoderSection = Annotated[SerializeAsAny[EncoderConfig], BeforeValidator(ENCODERS.parse)]


class CalibrationConfig(BaseModel):
    """Either ``path`` to a calibration JSON ({model_id, mu0, mu1, s}) or inline values."""

    model_config = ConfigDict(extra="forbid")
    path: str | None = None
    mu0: float | None = None
    mu1: float | None = None
    s: float | None = None
    model_id: str = "inline"

    @model_validator(mode="after")
    def _one_form(self) -> CalibrationConfig:
        inline = [v is not None for v in (self.mu0, self.mu1, self.s)]
        if self.path is None and not all(inline):
            raise ValueError("give either 'path' or all of 'mu0', 'mu1', 's'")
        if self.path is not None and any(inline):
            raise ValueError("give either 'path' or inline 'mu0', 'mu1', 's', not both")
        return self


class ModelProfile(BaseModel):
    """A named combination of segmenter, encoder and calibration."""

    model_config = ConfigDict(extra="forbid")
    name: str = "default"
    segmenter: SegmenterSection = Field(default_factory=lambda: SEGMENTERS.parse({}))
    encoder: EncoderSection
    calibration: CalibrationConfig | None = None


def _with_resolved_paths(profile: ModelProfile, base: Path) -> ModelProfile:
    update: dict[str, Any] = {
        "segmenter": profile.segmenter.resolved(base),
        "encoder": profile.encoder.resolved(base),
    }
    if profile.calibration is not None and profile.calibration.path is not None:
        update["calibration"] = profile.calibration.model_copy(
            update={"path": resolve_path(profile.calibration.path, base)}
        )
    return profile.model_copy(update=update)


def load_profile(source: str | Path | dict[str, Any], *, base_dir: str | Path | None = None) -> ModelProfile:
    """A profile from a YAML file or a dict; relative paths resolve against the file's folder
    (for a dict: ``base_dir``, default the working directory)."""
    if isinstance(source, dict):
        data, where, base = source, "profile", Path(base_dir or Path.cwd())
    else:
        path = Path(source)
        where, base = str(path), Path(base_dir) if base_dir else path.resolve().parent
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except FileNotFoundError as exc:
            raise InputError("profile file not found", source=where) from exc
        except (OSError, yaml.YAMLError) as exc:
            raise InputError(f"cannot read profile YAML: {exc}", source=where) from exc
    if not isinstance(data, dict):
        raise InputError("a profile must be a mapping", source=where)
    try:
        profile = ModelProfile.model_validate(data)
    except ValidationError as exc:
        fields = "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors())
        raise InputError(f"invalid profile: {fields}", source=where) from exc
    return _with_resolved_paths(profile, base)


def default_profile_path() -> Path:
    """``$BFIELDS_DEFAULT_PROFILE`` or the package's ``bayesian_fields_core/models/profiles/default.yaml``.

    The profile and the tiny CLIP it names are package data, so a wheel install (not only an
    editable checkout) finds them; the profile's relative paths resolve against its real folder.
    """
    env = os.environ.get(DEFAULT_PROFILE_ENV)
    if env:
        return Path(env)
    return Path(str(resources.files("bayesian_fields_core").joinpath("models", "profiles", "default.yaml")))


def default_profile() -> ModelProfile:
    """The bundled profile: classical segmenter + the project's tiny CLIP and its calibration."""
    path = default_profile_path()
    if not path.is_file():
        raise ModelError(f"{path}: default model profile not found (set {DEFAULT_PROFILE_ENV})")
    return load_profile(path)


def build_segmenter(cfg: SegmenterConfig | ModelProfile, *, device: str | None = None) -> Segmenter:
    """The configured ``Segmenter`` (``device``, when given, overrides a device in its params)."""
    cfg = cfg.segmenter if isinstance(cfg, ModelProfile) else cfg
    return cfg.build(device=device)


def build_encoder(cfg: EncoderConfig | ModelProfile, *, device: str | None = None) -> Encoder:
    """The configured ``Encoder``; ``device`` (when given) overrides the profile's."""
    cfg = cfg.encoder if isinstance(cfg, ModelProfile) else cfg
    return cfg.build(device=device)


def encoder_model_id(cfg: EncoderConfig | ModelProfile) -> str:
    """The encoder's ``model_id`` computed from its files, without loading the model."""
    cfg = cfg.encoder if isinstance(cfg, ModelProfile) else cfg
    return cfg.model_id()


def load_profile_calibration(profile: ModelProfile, *, model_id: str | None = None) -> Calibration | None:
    """The profile's calibration (None when it has none: the paper's defaults apply).

    With ``model_id``, a calibration file made for another encoder is refused.
    """
    cal = profile.calibration
    if cal is None:
        return None
    if cal.path is not None:
        return load_calibration(cal.path, model_id=model_id)
    try:
        # validated here: an inline calibration may lack mu0 / mu1 / s
        return Calibration.model_validate(
            {"model_id": cal.model_id, "mu0": cal.mu0, "mu1": cal.mu1, "s": cal.s}
        )
    except ValidationError as exc:
        raise InputError(f"invalid inline calibration: {exc}", source="profile.calibration") from exc


def profile_fingerprint(profile: ModelProfile) -> str:
    """16 hex characters identifying what the perceive stage would produce with this profile."""
    identity = {
        "segmenter": profile.segmenter.identity(),
        "encoder": profile.encoder.identity(),
        "crops": CROP_SETTINGS,
    }
    blob = json.dumps(identity, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]
