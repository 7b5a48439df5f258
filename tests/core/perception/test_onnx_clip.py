"""OnnxClipEncoder on the tiny CLIP's towers exported to ONNX: same embeddings as HF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.hf_clip import HFClipEncoder
from bayesian_fields_core.perception.onnx_clip import OnnxClipEncoder
from bayesian_fields_core.perception.onnx_export import export_clip_onnx

# Slow (the inner loop leaves it out): its fixtures took 2.1 s to set up here (--durations).
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def onnx_clip_dir(tiny_clip_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return export_clip_onnx(tiny_clip_dir, tmp_path_factory.mktemp("onnx") / "tiny-clip-onnx")


def test_onnx_matches_hf(tiny_clip_dir: Path, onnx_clip_dir: Path) -> None:
    hf = HFClipEncoder(tiny_clip_dir)
    ox = OnnxClipEncoder(onnx_clip_dir)
    assert ox.dim == hf.dim == 16
    assert ox.model_id.startswith("tiny-clip-onnx@") and ox.model_id != hf.model_id
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (30 + 7 * i, 50 - 5 * i, 3), dtype=np.uint8) for i in range(6)]
    assert np.abs(ox.encode_images(images) - hf.encode_images(images)).max() < 1e-4
    texts = ["a red chair", "the mug on a table", "plant", "blue blue blue cup of the"]
    assert np.abs(ox.encode_texts(texts) - hf.encode_texts(texts)).max() < 1e-4
    assert ox.encode_images([]).shape == (0, 16) and ox.encode_texts([]).shape == (0, 16)


def test_missing_files(onnx_clip_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="image_encoder.onnx"):
        OnnxClipEncoder(tmp_path)
    (tmp_path / "image_encoder.onnx").write_bytes(b"not onnx")
    with pytest.raises(ModelError, match="cannot load ONNX"):
        OnnxClipEncoder(tmp_path, text_model="../" + str(onnx_clip_dir / "text_encoder.onnx"))
