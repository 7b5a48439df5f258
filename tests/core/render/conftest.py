"""Renderer test configuration."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _single_thread():
    """Run the renderer single-threaded in tests.

    The test machine is shared by several concurrent test runs; with oversubscribed cores,
    OpenMP barriers in torch's many small parallel ops cost far more than the parallelism gains.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
