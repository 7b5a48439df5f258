"""The bounded perception pipeline (`pipelined`) and cross-frame crop batching (`CropBatcher`)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.perception.batching import CropBatcher
from bayesian_fields_core.perception.crops import mask_crops
from bayesian_fields_core.perception.hf_clip import HFClipEncoder
from bayesian_fields_core.perception.prefetch import pipelined


@pytest.mark.parametrize("depth", [0, 1, 3])
def test_pipelined_keeps_order_and_applies_every_step(depth: int) -> None:
    out = list(pipelined(range(50), [lambda x: x + 1, lambda x: x * 10, str], depth))
    assert out == [str((x + 1) * 10) for x in range(50)]


def test_pipelined_runs_steps_in_other_threads_and_bounds_the_lookahead() -> None:
    produced: list[int] = []
    seen_threads: set[int] = set()

    def step(x: int) -> int:
        seen_threads.add(threading.get_ident())
        produced.append(x)
        return x

    gen = pipelined(range(1000), [step], depth=2)
    assert next(gen) == 0
    time.sleep(0.5)  # let the threads run ahead as far as the queues allow
    # One item held by the caller, two in each queue, one in the step's hands: never the stream.
    assert len(produced) <= 1 + 2 * 2 + 2
    assert threading.get_ident() not in seen_threads
    gen.close()  # leaving early stops the threads


def test_pipelined_reraises_a_step_error_in_the_caller() -> None:
    def bad(x: int) -> int:
        if x == 3:
            raise ValueError("frame 3 is broken")
        return x

    got = []
    with pytest.raises(ValueError, match="frame 3 is broken"):
        for x in pipelined(range(10), [bad], depth=2):
            got.append(x)
    assert got == [0, 1, 2]
    with pytest.raises(ValueError):
        pipelined(range(3), [bad], depth=-1).__next__()


def _frames(image: np.ndarray, n: int) -> list[tuple[int, np.ndarray]]:
    """n label images of 0..5 vertical stripes (frame k has k % 6 masks; some have none)."""
    out = []
    for k in range(n):
        labels = np.full(image.shape[:2], -1, dtype=np.int32)
        for m in range(k % 6):
            labels[:, m * 12 : m * 12 + 10] = m
        out.append((k, labels))
    return out


@pytest.mark.parametrize("batch_size", [1, 4, 7, 1000])
@pytest.mark.slow
def test_crop_batcher_matches_per_frame_encoding(
    batch_size: int, tiny_clip_dir: Path, scene_image: np.ndarray
) -> None:
    enc = HFClipEncoder(tiny_clip_dir)
    frames = _frames(scene_image, 9)
    reference = {
        k: enc.encode_images(mask_crops(scene_image, lab)) if lab.max() >= 0 else None for k, lab in frames
    }
    batcher = CropBatcher(enc, batch_size)
    got: dict[int, np.ndarray] = {}
    for k, lab in frames:
        for key, emb in batcher.add(k, mask_crops(scene_image, lab)):
            got[key] = emb
    for key, emb in batcher.flush():
        got[key] = emb
    assert sorted(got) == list(range(9))
    total = sum(k % 6 for k in range(9))
    assert batcher.calls == -(-total // batch_size)  # full batches across frames, one remainder
    for k, _lab in frames:
        assert got[k].shape == (k % 6, enc.dim) and got[k].dtype == np.float32
        if reference[k] is not None:
            np.testing.assert_allclose(got[k], reference[k], atol=1e-5)


def test_crop_batcher_refuses_a_zero_batch(tiny_clip_dir: Path) -> None:
    with pytest.raises(ValueError, match="batch_size"):
        CropBatcher(HFClipEncoder(tiny_clip_dir), 0)
