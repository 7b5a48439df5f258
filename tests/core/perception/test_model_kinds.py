"""Adding a model kind is one class: two kinds defined here (a grid segmenter and a palette
encoder) are registered by their decorator alone and then read, built, identified and refused
through the same profile path as the bundled kinds (YAML -> ``load_models`` -> ``Models``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
import yaml

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.perception import profiles as registry
from bayesian_fields_core.perception.digest import files_digest
from bayesian_fields_core.perception.encoder import Encoder, l2_normalize
from bayesian_fields_core.perception.kind_base import (
    ENCODERS,
    SEGMENTERS,
    EncoderConfig,
    KindParams,
    Runtime,
    SegmenterConfig,
)
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.perception.segmenter import Segmenter


class GridSegmenter:
    """Square cells of ``cell`` pixels, numbered row by row (exclusive by construction)."""

    name = "test-grid"

    def __init__(self, cell: int, device: str = "cpu") -> None:
        self.cell, self.device = cell, device
        self.params: dict[str, Any] = {"cell": cell}

    def segment(self, image: np.ndarray) -> np.ndarray:
        h, w = image.shape[:2]
        rows, cols = np.arange(h)[:, None] // self.cell, np.arange(w)[None, :] // self.cell
        return (rows * (-(-w // self.cell)) + cols).astype(np.int32)


class PaletteEncoder:
    """Images by their mean colour, texts by the first palette word they contain (RGB in [0, 1])."""

    def __init__(self, palette: Path) -> None:
        self.palette = json.loads(palette.read_text())
        self.model_id = palette_model_id(palette)
        self.dim = 3

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        rows = [im.reshape(-1, 3).mean(axis=0) / 255.0 for im in images]
        return l2_normalize(np.array(rows, dtype=np.float32).reshape(-1, 3))

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        def colour(text: str) -> list[float]:
            return next((self.palette[w] for w in text.split() if w in self.palette), [0.0, 0.0, 0.0])

        return l2_normalize(np.array([colour(t) for t in texts], dtype=np.float32))


def palette_model_id(palette: Path) -> str:
    return f"palette@{files_digest([palette])}"


@SEGMENTERS.register
class GridKind(SegmenterConfig):
    """The whole of what a new segmenter kind needs."""

    class Params(KindParams):
        cell: int
        device: Runtime[str | None] = None

    kind: Literal["test-grid"] = "test-grid"
    params: Params

    def build(self, *, device: str | None = None) -> Segmenter:
        return GridSegmenter(**(self.params.kwargs() | ({"device": device} if device else {})))


@ENCODERS.register
class PaletteKind(EncoderConfig):
    """The whole of what a new encoder kind needs: params, factory and model-id rule."""

    class Params(KindParams):
        pass

    kind: Literal["test-palette"] = "test-palette"
    params: Params = Params()

    def build(self, *, device: str | None = None) -> Encoder:
        return PaletteEncoder(Path(self.path))

    def model_id(self) -> str:
        return palette_model_id(Path(self.path))


def _write(folder: Path, cell: int = 8, device: str = "cpu", **extra: Any) -> Path:
    (folder / "models").mkdir(parents=True, exist_ok=True)
    (folder / "models" / "palette.json").write_text(json.dumps({"red": [1, 0, 0], "blue": [0, 0, 1]}))
    (folder / "profiles").mkdir(exist_ok=True)
    doc = {
        "name": "dummy",
        "segmenter": {"kind": "test-grid", "params": {"cell": cell, "device": device, **extra}},
        "encoder": {"kind": "test-palette", "path": "../models/palette.json"},
        "calibration": {"mu0": 0.5, "mu1": 0.9, "s": 0.1},
    }
    path = folder / "profiles" / "dummy.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_a_kind_defined_here_runs_through_the_profile_path(tmp_path: Path) -> None:
    models = load_models(_write(tmp_path))  # what `bfields run --profile` does
    assert isinstance(models.profile.segmenter, GridKind) and isinstance(models.profile.encoder, PaletteKind)
    # The encoder's relative path resolved against the profile's folder.
    assert Path(models.profile.encoder.path) == (tmp_path / "models" / "palette.json").resolve()
    seg, enc = models.segmenter, models.encoder
    assert isinstance(seg, Segmenter) and isinstance(enc, Encoder)
    image = np.zeros((20, 30, 3), np.uint8)
    image[:, 15:, 2] = 255
    labels = seg.segment(image)
    assert labels.shape == (20, 30) and labels.max() == 3 * 4 - 1  # 3 rows x 4 columns of 8-px cells
    left, right = enc.encode_images([image[:, :15], image[:, 15:]])
    texts = enc.encode_texts(["a blue cup", "a red cup"])
    assert float(right @ texts[0]) == pytest.approx(1.0) and float(left @ texts[1]) == 0.0
    ids = models.model_ids
    assert ids["segmenter"] == "test-grid" and ids["encoder"] == enc.model_id
    assert ids["encoder"].startswith("palette@") and ids["calibration"] == "inline"


def test_the_new_kind_is_fingerprinted_and_refused_like_the_bundled_ones(tmp_path: Path) -> None:
    base = registry.profile_fingerprint(load_models(_write(tmp_path / "a")).profile)
    # A runtime setting does not change the fingerprint; a param and the model file's content do.
    assert registry.profile_fingerprint(load_models(_write(tmp_path / "b", device="cuda")).profile) == base
    assert registry.profile_fingerprint(load_models(_write(tmp_path / "c", cell=4)).profile) != base
    path = _write(tmp_path / "d")
    (path.parent.parent / "models" / "palette.json").write_text(json.dumps({"red": [1, 0, 0]}))
    assert registry.profile_fingerprint(registry.load_profile(path)) != base
    # Unknown keys and wrong types: one line naming the profile file and the field.
    with pytest.raises(InputError, match=r"dummy\.yaml: invalid profile: segmenter\.params\.celll: Extra"):
        registry.load_profile(_write(tmp_path / "e", celll=3))
    with pytest.raises(InputError, match=r"segmenter\.params\.cell: Input should be a valid integer"):
        registry.load_profile(_write(tmp_path / "f", cell="big"))
    with pytest.raises(
        InputError, match=r"segmenter\.kind: unknown kind 'test-gird' \(did you mean 'test-grid'\?\)"
    ):
        registry.load_profile(
            {"segmenter": {"kind": "test-gird"}, "encoder": {"kind": "test-palette", "path": "p"}}
        )


def test_a_kind_name_is_registered_once() -> None:
    with pytest.raises(ValueError, match="already registered"):

        @SEGMENTERS.register
        class Other(SegmenterConfig):  # same name as the bundled classical kind
            kind: Literal["classical"] = "classical"
            params: KindParams = KindParams()

            def build(self, *, device: str | None = None) -> Segmenter:
                raise AssertionError

    assert SEGMENTERS.get("classical").__name__ == "ClassicalKind"
    assert {"test-grid", "classical", "fastsam", "onnx"} <= set(SEGMENTERS.names())
    assert {"test-palette", "hf_clip", "onnx", "open_clip"} <= set(ENCODERS.names())
