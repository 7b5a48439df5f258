"""HFClipEncoder with a real (random-init) tiny CLIPModel loaded from disk."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from transformers import CLIPImageProcessor, CLIPModel

from bayesian_fields_core.errors import InputError, ModelError
from bayesian_fields_core.perception.clip_inputs import ClipImagePreprocessor
from bayesian_fields_core.perception.encoder import Encoder
from bayesian_fields_core.perception.hf_clip import HFClipEncoder, hf_clip_model_id


def _images(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [
        rng.integers(0, 256, (int(rng.integers(20, 70)), int(rng.integers(20, 70)), 3), dtype=np.uint8)
        for _ in range(n)
    ]


def test_preprocessing_matches_transformers_image_processor(tiny_clip_dir: Path) -> None:
    ours = ClipImagePreprocessor.from_folder(tiny_clip_dir)
    theirs = CLIPImageProcessor.from_pretrained(str(tiny_clip_dir), local_files_only=True)
    images = _images(4)
    ref = np.asarray(theirs(images=images, return_tensors="np")["pixel_values"])
    got = ours(images)
    assert got.shape == ref.shape == (4, 3, 32, 32)
    assert np.abs(got - ref).max() < 2e-2  # same PIL bicubic resize; float rounding only


def test_square_mode_keeps_whole_image(tiny_clip_dir: Path) -> None:
    pre = ClipImagePreprocessor.from_folder(tiny_clip_dir, mode="square")
    img = np.zeros((20, 80, 3), dtype=np.uint8)
    img[:, :10] = 255  # a white strip on the far left, cropped away by shortest_crop
    sq = pre([img])[0]
    crop = ClipImagePreprocessor.from_folder(tiny_clip_dir)([img])[0]
    assert sq[:, :, 0].mean() > 1.0 and crop[:, :, 0].mean() < -1.0


@pytest.mark.slow
def test_embeddings_match_model_and_are_normalised(tiny_clip_dir: Path) -> None:
    enc = HFClipEncoder(tiny_clip_dir)
    assert isinstance(enc, Encoder) and enc.dim == 16
    images = _images(5)
    emb = enc.encode_images(images)
    assert emb.shape == (5, 16) and emb.dtype == np.float32
    assert np.allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    # Same numbers as running the model directly on our pixel values.
    model = CLIPModel.from_pretrained(str(tiny_clip_dir), local_files_only=True).eval()
    with torch.inference_mode():
        out = model.get_image_features(pixel_values=torch.from_numpy(enc.preprocess(images)))
    ref = getattr(out, "pooler_output", out).numpy()
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    assert np.allclose(emb, ref, atol=1e-5)
    # One image alone gives the same embedding as in the batch; chunking changes nothing.
    assert np.allclose(enc.encode_images(images[2:3])[0], emb[2], atol=1e-5)
    chunked = HFClipEncoder(tiny_clip_dir, max_batch=2)
    assert np.allclose(chunked.encode_images(images), emb, atol=1e-5)
    assert enc.encode_images([]).shape == (0, 16)


def test_text_embeddings(tiny_clip_dir: Path) -> None:
    enc = HFClipEncoder(tiny_clip_dir)
    texts = ["a red chair", "a photo of the green plant on the table", "cup"]
    emb = enc.encode_texts(texts)
    assert emb.shape == (3, 16)
    assert np.allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    # Padding does not change a text's embedding.
    for i, t in enumerate(texts):
        assert np.allclose(enc.encode_texts([t])[0], emb[i], atol=1e-5)
    assert not np.allclose(emb[0], emb[1])
    # Truncation at the context length (16) instead of an error.
    assert enc.encode_texts(["a " * 50]).shape == (1, 16)
    assert enc.encode_texts([]).shape == (0, 16)


def test_model_id_names_weights_not_path(tiny_clip_dir: Path, tmp_path: Path) -> None:
    mid = hf_clip_model_id(tiny_clip_dir)
    assert mid.startswith("tiny-clip@") and len(mid.split("@")[1]) == 12
    copy = shutil.copytree(tiny_clip_dir, tmp_path / "tiny-clip")
    assert hf_clip_model_id(copy) == mid
    other = tmp_path / "other" / "tiny-clip"
    from tests.core.perception.conftest import make_tiny_clip

    make_tiny_clip(other, seed=1)
    assert hf_clip_model_id(other) != mid


def test_errors(tiny_clip_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="config.json"):
        HFClipEncoder(tmp_path)
    enc = HFClipEncoder(tiny_clip_dir)
    with pytest.raises(InputError, match=r"images\[1\]"):
        enc.encode_images([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8), np.uint8)])


def test_reduced_precision_dtype_is_close_and_fingerprinted(
    tiny_clip_dir: Path, scene_image: np.ndarray
) -> None:
    full = HFClipEncoder(tiny_clip_dir)
    half = HFClipEncoder(tiny_clip_dir, dtype="bfloat16")  # float16 matmuls need a GPU; bf16 runs on CPUs
    assert "dtype" not in full.params and half.params["dtype"] == "bfloat16"
    crops = [scene_image[5:25, 5:35], scene_image[10:50, 45:75]]
    a, b = full.encode_images(crops), half.encode_images(crops)
    assert b.dtype == np.float32 and b.shape == a.shape
    assert ((a * b).sum(axis=1) > 0.98).all()
    with pytest.raises(ModelError, match="dtype"):
        HFClipEncoder(tiny_clip_dir, dtype="int8")
