"""The fusion state's memory: the fuse stage writes the (N, T) probabilities block by block and a
local reader decompresses in place, so neither holds the state twice (docs: Performance and
scaling, the fusion state).

At 5M Gaussians x 100 tasks the float32 log-odds are 2 GB; writing the artifact the old way
(probabilities computed whole, then the compressed archive built in a BytesIO and copied out by
`getvalue()`) held about three times that again. These tests pin the results (bit-identical to
the whole-array path) and the memory bound (tracemalloc sees numpy's buffers and zlib's).
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from bayesian_fields_core.errors import InvariantError
from bayesian_fields_core.fusion.bayes import probabilities, probability_blocks
from bayesian_fields_core.job.store import (
    ArrayBlocks,
    ArtifactNotFound,
    LocalStore,
    PrefixedStore,
    get_arrays,
    put_array_blocks,
    put_arrays,
)


def _logodds(rows: int, tasks: int, seed: int = 0) -> np.ndarray:
    """Log-odds as fusion leaves them: the prior for unseen Gaussians, sums of llr elsewhere."""
    rng = np.random.default_rng(seed)
    state = np.full((rows, tasks), -2.944439, dtype=np.float32)
    seen = rng.random(rows) < 0.8
    state[seen] += rng.normal(0.0, 4.0, (int(seen.sum()), tasks)).astype(np.float32)
    return state


def test_probability_blocks_are_the_whole_probabilities() -> None:
    logodds = _logodds(10_003, 7)
    blocks = list(probability_blocks(logodds, block_bytes=4 * 7 * 1000))
    assert [len(b) for b in blocks] == [1000] * 10 + [3]
    whole = probabilities(logodds)
    assert all(b.dtype == np.float32 for b in blocks)
    np.testing.assert_array_equal(np.concatenate(blocks), whole)


@pytest.mark.parametrize("prefixed", [False, True], ids=["local", "through put_file"])
def test_block_written_npz_reads_back_like_put_arrays(tmp_path: Path, prefixed: bool) -> None:
    local = LocalStore(tmp_path / "store")
    store = PrefixedStore(local, "job/") if prefixed else local
    logodds = _logodds(5_001, 26)
    observed = np.random.default_rng(1).random(5_001) < 0.5
    put_array_blocks(
        store,
        "fusion/state.npz",
        probabilities=ArrayBlocks(
            logodds.shape, np.dtype(np.float32), probability_blocks(logodds, 4 * 26 * 777)
        ),
        logodds=logodds,
        observed=observed,
    )
    put_arrays(
        store, "fusion/whole.npz", probabilities=probabilities(logodds), logodds=logodds, observed=observed
    )
    streamed, whole = get_arrays(store, "fusion/state.npz"), get_arrays(store, "fusion/whole.npz")
    assert sorted(streamed) == sorted(whole) == ["logodds", "observed", "probabilities"]
    for name in whole:
        assert streamed[name].dtype == whole[name].dtype and streamed[name].shape == whole[name].shape
        np.testing.assert_array_equal(streamed[name], whole[name])
    # a plain np.load reads it too (the viewer and users open the file directly)
    path = local.local_path(("job/" if prefixed else "") + "fusion/state.npz")
    with np.load(path, allow_pickle=False) as data:
        np.testing.assert_array_equal(data["probabilities"], whole["probabilities"])
    assert not list(path.parent.glob(".tmp-*"))


def test_blocks_that_disagree_with_the_shape_are_refused_and_leave_nothing(tmp_path: Path) -> None:
    store = LocalStore(tmp_path)
    short = ArrayBlocks((10, 3), np.dtype(np.float32), [np.zeros((4, 3)), np.zeros((4, 3))])
    with pytest.raises(InvariantError, match="8 rows"):
        put_array_blocks(store, "a.npz", x=short)
    wide = ArrayBlocks((4, 3), np.dtype(np.float32), [np.zeros((4, 2))])
    with pytest.raises(InvariantError, match="shape"):
        put_array_blocks(store, "a.npz", x=wide)
    assert not store.exists("a.npz") and not list(tmp_path.glob(".tmp-*"))
    with pytest.raises(ArtifactNotFound):
        get_arrays(store, "a.npz")


def _peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        fn()
        return tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_state_write_holds_one_block_not_the_probabilities(tmp_path: Path) -> None:
    """The fuse stage's write: peak extra memory is a block, not the (N, T) probabilities (the old
    write's peak was the probabilities plus the compressed archive twice: ~2.5x the state)."""
    store = LocalStore(tmp_path)
    logodds = _logodds(400_000, 26)  # 41.6 MB, the scale bench's state
    block = 2**20

    def write() -> None:
        put_array_blocks(
            store,
            "fusion/gaussian_probabilities.npz",
            block_bytes=block,
            probabilities=ArrayBlocks(
                logodds.shape, np.dtype(np.float32), probability_blocks(logodds, block)
            ),
            logodds=logodds,
        )

    peak = _peak_bytes(write)
    assert peak < 0.15 * logodds.nbytes, (
        f"peak {peak / 2**20:.1f} MiB for a {logodds.nbytes / 2**20:.1f} MiB state"
    )
    np.testing.assert_array_equal(get_arrays(store, "fusion/gaussian_probabilities.npz")["logodds"], logodds)


@pytest.mark.slow
def test_local_read_holds_the_arrays_not_also_the_archive(tmp_path: Path) -> None:
    store = LocalStore(tmp_path)
    state = np.random.default_rng(2).random((200_000, 26), dtype=np.float32)  # barely compressible
    put_arrays(store, "fusion/x.npz", x=state)
    assert store.size("fusion/x.npz") > 0.8 * state.nbytes
    out: dict = {}
    peak = _peak_bytes(lambda: out.update(get_arrays(store, "fusion/x.npz")))
    # the array itself plus zlib's buffers; reading the bytes first would add ~0.9x more
    assert peak < 1.2 * state.nbytes, f"peak {peak / 2**20:.1f} MiB for {state.nbytes / 2**20:.1f} MiB"
    np.testing.assert_array_equal(out["x"], state)
