"""Model profiles: YAML loading, path resolution, building real components, calibration, fingerprint."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from bayesian_fields_core.calibration.model import Calibration, save_calibration
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception import profiles as registry
from bayesian_fields_core.perception.classical import ClassicalSegmenter
from bayesian_fields_core.perception.hf_clip import HFClipEncoder, hf_clip_model_id
from bayesian_fields_core.perception.onnx_clip import OnnxClipEncoder
from bayesian_fields_core.perception.onnx_export import export_clip_onnx

REPO = Path(__file__).resolve().parents[3]
MODELS = REPO / "bayesian_fields_core" / "models"  # the shipped profiles and tiny CLIP (package data)


def _profile_dir(tmp_path: Path, tiny_clip_dir: Path, **segmenter_params: object) -> Path:
    """profiles/p.yaml next to models/tiny-clip (+ calibration.json), with relative paths."""
    models = tmp_path / "models"
    clip = shutil.copytree(tiny_clip_dir, models / "tiny-clip")
    save_calibration(
        clip / "calibration.json", Calibration(model_id=hf_clip_model_id(clip), mu0=0.1, mu1=0.3, s=0.05)
    )
    (models / "profiles").mkdir()
    doc = {
        "name": "test",
        "segmenter": {"kind": "classical", "params": {"scale": 50, "min_area": 10, **segmenter_params}},
        "encoder": {"kind": "hf_clip", "path": "../tiny-clip"},
        "calibration": {"path": "../tiny-clip/calibration.json"},
    }
    (models / "profiles" / "p.yaml").write_text(yaml.safe_dump(doc))
    return models


def test_yaml_profile_builds_real_components(
    tmp_path: Path, tiny_clip_dir: Path, scene_image: np.ndarray
) -> None:
    models = _profile_dir(tmp_path, tiny_clip_dir)
    prof = registry.load_profile(models / "profiles" / "p.yaml")
    assert prof.name == "test" and Path(prof.encoder.path) == (models / "tiny-clip").resolve()
    seg = registry.build_segmenter(prof)
    enc = registry.build_encoder(prof.encoder, device="cpu")
    assert isinstance(seg, ClassicalSegmenter) and seg.scale == 50 and seg.min_area == 10
    assert isinstance(enc, HFClipEncoder) and enc.model_id == registry.encoder_model_id(prof.encoder)
    labels = seg.segment(scene_image)
    assert labels.max() >= 3
    cal = registry.load_profile_calibration(prof, model_id=enc.model_id)
    assert cal is not None and (cal.mu0, cal.mu1, cal.s) == (0.1, 0.3, 0.05)
    with pytest.raises(InputError, match="calibration is for model"):
        registry.load_profile_calibration(prof, model_id="other@123")


@pytest.mark.slow
def test_onnx_encoder_profile(tmp_path: Path, tiny_clip_dir: Path) -> None:
    export_clip_onnx(tiny_clip_dir, tmp_path / "clip-onnx")
    prof = registry.load_profile(
        {"encoder": {"kind": "onnx", "path": "clip-onnx", "params": {"threads": 1}}}, base_dir=tmp_path
    )
    enc = registry.build_encoder(prof)
    assert isinstance(enc, OnnxClipEncoder) and enc.model_id == registry.encoder_model_id(prof.encoder)
    assert registry.load_profile_calibration(prof) is None


def test_fingerprint_stable_and_sensitive(tmp_path: Path, tiny_clip_dir: Path) -> None:
    a = _profile_dir(tmp_path / "a", tiny_clip_dir)
    b = _profile_dir(tmp_path / "b", tiny_clip_dir)
    fa = registry.profile_fingerprint(registry.load_profile(a / "profiles" / "p.yaml"))
    fb = registry.profile_fingerprint(registry.load_profile(b / "profiles" / "p.yaml"))
    assert fa == fb and len(fa) == 16  # same models and params in another folder
    # Explicit defaults and runtime-only settings do not change it.
    prof = registry.load_profile(a / "profiles" / "p.yaml")
    same = prof.model_copy(
        update={
            "segmenter": prof.segmenter.model_copy(
                update={"params": prof.segmenter.params.model_copy(update={"sigma": 0.8})}
            ),
            "encoder": prof.encoder.model_copy(
                update={"device": "cuda", "params": type(prof.encoder.params)(max_batch=8)}
            ),
        }
    )
    assert registry.profile_fingerprint(same) == fa
    c = _profile_dir(tmp_path / "c", tiny_clip_dir, scale=60)
    assert registry.profile_fingerprint(registry.load_profile(c / "profiles" / "p.yaml")) != fa
    resize = prof.model_copy(
        update={
            "encoder": prof.encoder.model_copy(
                update={"params": type(prof.encoder.params)(resize_mode="square")}
            )
        }
    )
    assert registry.profile_fingerprint(resize) != fa
    # New weights, same folder name: new fingerprint.
    from tests.core.perception.conftest import make_tiny_clip

    make_tiny_clip(b / "tiny-clip", seed=3)
    assert registry.profile_fingerprint(registry.load_profile(b / "profiles" / "p.yaml")) != fa


def test_inline_calibration_and_validation_errors(tmp_path: Path) -> None:
    enc = {"kind": "hf_clip", "path": "x"}
    prof = registry.load_profile({"encoder": enc, "calibration": {"mu0": 0.2, "mu1": 0.27, "s": 0.035}})
    cal = registry.load_profile_calibration(prof)
    assert cal is not None and cal.mu1 == 0.27 and cal.model_id == "inline"
    with pytest.raises(InputError, match="either 'path' or"):
        registry.load_profile({"encoder": enc, "calibration": {"mu0": 0.2}})
    with pytest.raises(InputError, match=r"segmenter\.kind: unknown kind 'sam9'; known: classical, fastsam"):
        registry.load_profile({"encoder": enc, "segmenter": {"kind": "sam9"}})
    with pytest.raises(InputError, match="encoder"):
        registry.load_profile({"segmenter": {"kind": "classical"}})
    # Per-kind params are typed: unknown keys, wrong types and missing files are refused on reading.
    with pytest.raises(
        InputError, match=r"^profile: invalid profile: segmenter\.params\.scael: Extra inputs"
    ):
        registry.load_profile({"encoder": enc, "segmenter": {"params": {"scael": 3}}})
    with pytest.raises(InputError, match=r"segmenter\.params\.weights: Field required"):
        registry.load_profile({"encoder": enc, "segmenter": {"kind": "fastsam"}})
    with pytest.raises(InputError, match=r"encoder\.params\.model_name: Field required"):
        registry.load_profile({"encoder": {"kind": "open_clip", "path": "x.pt"}})
    with pytest.raises(InputError, match=r"encoder\.params\.dtype: Input should be 'float32'"):
        registry.load_profile({"encoder": {**enc, "params": {"dtype": "float8"}}})
    (tmp_path / "typo.yaml").write_text("encoder: {kind: hf_clip, path: x, params: {resize: square}}\n")
    with pytest.raises(
        InputError, match=r"typo\.yaml: invalid profile: encoder\.params\.resize: Extra"
    ) as err:
        registry.load_profile(tmp_path / "typo.yaml")
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="not found"):
        registry.load_profile(tmp_path / "missing.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n")
    with pytest.raises(InputError, match="mapping"):
        registry.load_profile(tmp_path / "list.yaml")
    bad_cal = registry.load_profile({"encoder": enc, "calibration": {"mu0": 0.3, "mu1": 0.2, "s": 0.03}})
    with pytest.raises(InputError, match="inline calibration"):
        registry.load_profile_calibration(bad_cal)


def test_bundled_profiles(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, tiny_clip_dir: Path) -> None:
    prof = registry.default_profile()
    assert prof.segmenter.kind == "classical" and prof.encoder.kind == "hf_clip"
    assert Path(prof.encoder.path) == MODELS / "tiny-clip"
    assert prof.calibration is not None and prof.calibration.path == str(
        MODELS / "tiny-clip/calibration.json"
    )
    example = registry.load_profile(MODELS / "profiles" / "fastsam-clip-vitb16.yaml")
    assert example.segmenter.kind == "fastsam" and example.segmenter.params.weights.endswith(".pt")
    # The environment variable points the default elsewhere.
    models = _profile_dir(tmp_path, tiny_clip_dir)
    monkeypatch.setenv(registry.DEFAULT_PROFILE_ENV, str(models / "profiles" / "p.yaml"))
    assert registry.default_profile().name == "test"


@pytest.mark.skipif(not (MODELS / "tiny-clip" / "config.json").is_file(), reason="tiny-clip not built yet")
def test_bundled_default_profile_builds() -> None:
    prof = registry.default_profile()
    enc = registry.build_encoder(prof)
    assert enc.encode_texts(["a chair"]).shape == (1, enc.dim)
    assert len(registry.profile_fingerprint(prof)) == 16


def _docs() -> str:
    """Every page of the documentation site (`docs/`, build helpers aside), one after another."""
    pages = sorted(p for p in (REPO / "docs").rglob("*.md") if "_build" not in p.parts)
    return "\n".join(p.read_text(encoding="utf-8") for p in pages)


def test_docs_profile_examples_load() -> None:
    """Every profile in the docs (YAML blocks and inline sections) is valid for the typed kinds."""
    import re

    blocks = [yaml.safe_load(b) for b in re.findall(r"```yaml\n(.*?)```", _docs(), re.S)]
    profiles = [b for b in blocks if isinstance(b, dict) and "encoder" in b]
    assert len(profiles) >= 2
    for doc in profiles:
        registry.load_profile(doc, base_dir="/models")
    enc = {"kind": "hf_clip", "path": "x"}
    sections = [yaml.safe_load(s) for s in re.findall(r"`((?:segmenter|encoder): \{.*?\})`", _docs())]
    assert {next(iter(s)) for s in sections} == {"segmenter", "encoder"}
    for section in sections:
        registry.load_profile({"encoder": enc, **section})


def test_docs_kind_table_lists_every_kind_and_param() -> None:
    """The kind table of the docs' model profiles page names each registered kind and each of its
    params."""
    import re

    from bayesian_fields_core.perception.kind_base import ENCODERS, SEGMENTERS

    rows = {
        line.split("|")[1].strip(): line
        for line in _docs().splitlines()
        if line.startswith("| segmenter `") or line.startswith("| encoder `")
    }
    for section, kinds in (("segmenter", SEGMENTERS), ("encoder", ENCODERS)):
        for name in kinds.names():
            if name.startswith("test-"):  # the dummy kinds of test_model_kinds
                continue
            row = rows[f"{section} `{name}`"]
            params = kinds.get(name).model_fields["params"].annotation.model_fields
            missing = [p for p in params if not re.search(rf"`(params\.)?{p}`", row)]
            assert name == "classical" or not missing, f"docs row {section} {name} lacks {missing}"
