"""`single_blas_thread` sets every loaded OpenBLAS to one thread inside the block, restores the
previous counts after (also when the block raises), and leaves the products' values unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from bayesian_fields_core.objects.blas_threads import loaded_openblas, single_blas_thread


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
