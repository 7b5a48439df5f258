"""`single_blas_thread` sets every loaded OpenBLAS to one thread inside the block, restores the
previous counts after (also when the block raises), and leaves the products' values unchanged;
`torch_threads` does the same for torch's intra-op threads."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.compute.threads import loaded_openblas, single_blas_thread, torch_threads


def test_one_thread_inside_and_restored_after() -> None:
    controls = loaded_openblas()
    if not controls:
        pytest.skip("no OpenBLAS found in this process (no /proc, or another BLAS)")
    before = [get() for get, _ in controls]
    with pytest.raises(RuntimeError), single_blas_thread():
        assert [get() for get, _ in controls] == [1] * len(controls)
        raise RuntimeError("the block fails")
    assert [get() for get, _ in controls] == before


def test_products_are_the_same_floats() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(20_000, 3)), rng.normal(size=(3, 64))
    threaded = a @ b
    with single_blas_thread():
        single = a @ b
    np.testing.assert_array_equal(single, threaded)


def test_torch_threads_set_inside_and_restored_after() -> None:
    import torch

    before = torch.get_num_threads()
    with pytest.raises(RuntimeError), torch_threads(1):
        assert torch.get_num_threads() == 1
        raise RuntimeError("the block fails")
    assert torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before
