"""Fixtures: a random-init tiny CLIPModel folder (real transformers model and tokenizer files, made
once per session) and tmp HOME-like dirs so no tool writes into the real home directory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

WORDS = ["a", "photo", "of", "red", "green", "blue", "chair", "table", "cup", "plant", "the", "mug"]


def make_tiny_clip(folder: Path, seed: int = 0) -> Path:
    """Write a tiny random CLIPModel + word-level fast tokenizer + preprocessor config."""
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, processors
    from transformers import CLIPConfig, CLIPModel, PreTrainedTokenizerFast

    specials = ["[UNK]", "<|startoftext|>", "<|endoftext|>"]
    vocab = {w: i for i, w in enumerate(specials + WORDS)}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="[UNK]"))
    tok.normalizer = normalizers.Lowercase()
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    tok.post_processor = processors.TemplateProcessing(
        single="<|startoftext|> $A <|endoftext|>",
        special_tokens=[
            ("<|startoftext|>", vocab["<|startoftext|>"]),
            ("<|endoftext|>", vocab["<|endoftext|>"]),
        ],
    )
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok, unk_token="[UNK]", bos_token="<|startoftext|>", eos_token="<|endoftext|>"
    )
    torch.manual_seed(seed)
    config = CLIPConfig(
        text_config={
            "vocab_size": len(vocab),
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
            "max_position_embeddings": 16,
            "bos_token_id": vocab["<|startoftext|>"],
            "eos_token_id": vocab["<|endoftext|>"],
            "pad_token_id": vocab["<|endoftext|>"],
        },
        vision_config={
            "image_size": 32,
            "patch_size": 8,
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
        },
        projection_dim=16,
    )
    folder.mkdir(parents=True, exist_ok=True)
    CLIPModel(config).eval().save_pretrained(str(folder))
    fast.save_pretrained(str(folder))
    (folder / "preprocessor_config.json").write_text(
        json.dumps(
            {
                "size": {"shortest_edge": 32},
                "crop_size": {"height": 32, "width": 32},
                "image_mean": [0.48145466, 0.4578275, 0.40821073],
                "image_std": [0.26862954, 0.26130258, 0.27577711],
                "resample": 3,
            }
        )
    )
    return folder


@pytest.fixture(scope="session")
def tiny_clip_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_tiny_clip(tmp_path_factory.mktemp("models") / "tiny-clip")


@pytest.fixture(autouse=True)
def _home_in_tmp(tmp_home: Path) -> None:
    """Every perception test: HOME-writing tools (onnxruntime, ultralytics, HF) write inside tmp."""


@pytest.fixture
def scene_image() -> np.ndarray:
    """A 60x80 image with three flat coloured rectangles on gray."""
    img = np.full((60, 80, 3), 128, dtype=np.uint8)
    img[5:25, 5:35] = (220, 30, 30)
    img[30:55, 10:30] = (30, 200, 40)
    img[10:50, 45:75] = (40, 60, 220)
    return img
