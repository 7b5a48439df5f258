"""Model profiles: which segmenter, which CLIP encoder and which calibration a run uses.

A profile is a small YAML file the operator writes (models are files they provide; nothing is
downloaded)::

    name: default
    segmenter: {kind: classical, params: {method: felzenszwalb, scale: 300}}
    encoder: {kind: hf_clip, path: ../tiny-clip, params: {resize_mode: shortest_crop}}
    calibration: {path: ../tiny-clip/calibration.json}   # or {mu0: 0.2, mu1: 0.27, s: 0.035}

Relative paths (``encoder.path``, ``segmenter.params.weights`` / ``.path``, ``calibration.path``)
are resolved against the profile file's folder, so a profile travels with its models.
``profile_fingerprint`` hashes everything that changes the perception output (segmenter kind and
params with weight files replaced by their content hash, the encoder's model id and params, the
crop settings) and keys the per-scene perception cache; runtime-only settings (device, threads,
providers, batch size) are left out.
"""

from __future__ import annotations

import hashlib
import json
import os
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from bayesian_fields_core.calibration.model import Calibration, load_calibration
from bayesian_fields_core.errors import InputError, ModelError
from bayesian_fields_core.perception.digest import files_digest

# Segmenter params that name files (resolved against the profile folder, hashed in fingerprints).
SEGMENTER_PATH_KEYS = ("weights", "path")
# Settings that do not change the output: left out of the fingerprint.
RUNTIME_KEYS = frozenset({"device", "providers", "threads", "max_batch"})
# mask_crops defaults used by the perceive stage; part of the fingerprint so a change re-embeds.
CROP_SETTINGS = {"background": "gray", "pad_fraction": 0.1, "square": True}
DEFAULT_PROFILE_ENV = "BFIELDS_DEFAULT_PROFILE"


class SegmenterConfig(BaseModel):
    """``kind`` picks the class; ``params`` are its keyword arguments."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["classical", "fastsam", "onnx"] = "classical"
    params: dict[str, Any] = Field(default_factory=dict)


class EncoderConfig(BaseModel):
    """``path``: the HF model folder (hf_clip), the ONNX folder (onnx) or the checkpoint file
    (open_clip, with ``params.model_name``). ``params``: the encoder's other keyword arguments."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["hf_clip", "open_clip", "onnx"] = "hf_clip"
    path: str
    device: str = "cpu"
    params: dict[str, Any] = Field(default_factory=dict)


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
    segmenter: SegmenterConfig = Field(default_factory=SegmenterConfig)
    encoder: EncoderConfig
    calibration: CalibrationConfig | None = None


def _resolve(value: str, base: Path) -> str:
    p = Path(value).expanduser()
    return str(p if p.is_absolute() else (base / p).resolve())


def _with_resolved_paths(profile: ModelProfile, base: Path) -> ModelProfile:
    seg_params = {
        k: _resolve(v, base) if k in SEGMENTER_PATH_KEYS and isinstance(v, str) else v
        for k, v in profile.segmenter.params.items()
    }
    update: dict[str, Any] = {
        "segmenter": profile.segmenter.model_copy(update={"params": seg_params}),
        "encoder": profile.encoder.model_copy(update={"path": _resolve(profile.encoder.path, base)}),
    }
    if profile.calibration is not None and profile.calibration.path is not None:
        update["calibration"] = profile.calibration.model_copy(
            update={"path": _resolve(profile.calibration.path, base)}
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


def _construct(cls: Any, where: str, *args: Any, **kwargs: Any) -> Any:
    try:
        return cls(*args, **kwargs)
    except TypeError as exc:  # unknown or missing keyword in the profile's params
        raise InputError(f"bad parameters for {cls.__name__}: {exc}", source=where) from exc


def build_segmenter(cfg: SegmenterConfig | ModelProfile, *, device: str | None = None) -> Any:
    """The configured ``Segmenter`` (``device`` overrides FastSAM's ``params.device``)."""
    cfg = cfg.segmenter if isinstance(cfg, ModelProfile) else cfg
    params = dict(cfg.params)
    if cfg.kind == "classical":
        from bayesian_fields_core.perception.classical import ClassicalSegmenter

        return _construct(ClassicalSegmenter, "segmenter.params", **params)
    if cfg.kind == "fastsam":
        from bayesian_fields_core.perception.fastsam import FastSAMSegmenter

        if device is not None:
            params["device"] = device
        if "weights" not in params:
            raise InputError("fastsam needs params.weights (the FastSAM .pt file)", source="segmenter.params")
        return _construct(FastSAMSegmenter, "segmenter.params", **params)
    from bayesian_fields_core.perception.onnx_segmenter import OnnxSegmenter

    if "path" not in params:
        raise InputError("onnx segmenter needs params.path (the .onnx file)", source="segmenter.params")
    return _construct(OnnxSegmenter, "segmenter.params", **params)


def build_encoder(cfg: EncoderConfig | ModelProfile, *, device: str | None = None) -> Any:
    """The configured ``Encoder``; ``device`` (when given) overrides the profile's."""
    cfg = cfg.encoder if isinstance(cfg, ModelProfile) else cfg
    params = dict(cfg.params)
    dev = device or cfg.device
    if cfg.kind == "hf_clip":
        from bayesian_fields_core.perception.hf_clip import HFClipEncoder

        return _construct(HFClipEncoder, "encoder.params", cfg.path, device=dev, **params)
    if cfg.kind == "onnx":
        from bayesian_fields_core.perception.onnx_clip import OnnxClipEncoder

        return _construct(OnnxClipEncoder, "encoder.params", cfg.path, **params)
    from bayesian_fields_core.perception.open_clip_encoder import OpenClipEncoder

    if "model_name" not in params:
        raise InputError("open_clip needs params.model_name (e.g. ViT-B-16)", source="encoder.params")
    return _construct(OpenClipEncoder, "encoder.params", checkpoint=cfg.path, device=dev, **params)


def encoder_model_id(cfg: EncoderConfig) -> str:
    """The encoder's ``model_id`` computed from its files, without loading the model."""
    if cfg.kind == "hf_clip":
        from bayesian_fields_core.perception.hf_clip import hf_clip_model_id

        return hf_clip_model_id(cfg.path)
    if cfg.kind == "onnx":
        from bayesian_fields_core.perception.onnx_clip import onnx_clip_model_id

        names = {k: cfg.params[k] for k in ("image_model", "text_model") if k in cfg.params}
        return onnx_clip_model_id(cfg.path, **names)
    from bayesian_fields_core.perception.open_clip_encoder import open_clip_model_id

    return open_clip_model_id(str(cfg.params.get("model_name", "")), cfg.path)


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
        return Calibration(model_id=cal.model_id, mu0=cal.mu0, mu1=cal.mu1, s=cal.s)
    except ValidationError as exc:
        raise InputError(f"invalid inline calibration: {exc}", source="profile.calibration") from exc


def _segmenter_identity(cfg: SegmenterConfig) -> dict[str, Any]:
    if cfg.kind == "classical":
        params = build_segmenter(cfg).params  # cheap; fills in the defaults
    else:
        params = {
            k: files_digest([v]) if k in SEGMENTER_PATH_KEYS and isinstance(v, str) else v
            for k, v in cfg.params.items()
        }
    return {"kind": cfg.kind, "params": {k: v for k, v in params.items() if k not in RUNTIME_KEYS}}


def profile_fingerprint(profile: ModelProfile) -> str:
    """16 hex characters identifying what the perceive stage would produce with this profile."""
    identity = {
        "segmenter": _segmenter_identity(profile.segmenter),
        "encoder": {
            "kind": profile.encoder.kind,
            "model_id": encoder_model_id(profile.encoder),
            "params": {k: v for k, v in profile.encoder.params.items() if k not in RUNTIME_KEYS},
        },
        "crops": CROP_SETTINGS,
    }
    blob = json.dumps(identity, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]
