"""`StageMeter`'s GPU figures (issue 44, item 2): on CUDA, the peak GPU memory of the stage (the
peak reset at its start, so an earlier stage's larger peak is not reported again) and its wall time
as GPU-seconds; on a CPU worker, and wherever CUDA is absent, both are 0, as the docs say.
The CUDA case runs only where a GPU is present (skipped, saying so, elsewhere)."""

from __future__ import annotations

import time

import pytest
import torch

from bayesian_fields_service.worker.accounting import StageMeter


def test_a_cpu_worker_reports_zero_gpu_seconds_and_memory() -> None:
    with StageMeter(gpu=False) as meter:
        sum(range(200_000))
        time.sleep(0.05)
    assert meter.wall_s >= 0.05 and meter.cpu_s > 0
    assert meter.gpu_s == 0.0 and meter.gpu_peak_bytes == 0


@pytest.mark.skipif(torch.cuda.is_available(), reason="the no-CUDA branch: this host has CUDA")
def test_a_worker_told_gpu_without_cuda_reports_zero_memory() -> None:
    with StageMeter(gpu=True) as meter:
        time.sleep(0.01)
    assert meter.gpu_peak_bytes == 0 and meter.gpu_s == meter.wall_s > 0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this host")
def test_on_cuda_the_peak_is_this_stages_own() -> None:
    big = torch.empty(256 * 2**20, dtype=torch.uint8, device="cuda")  # an earlier stage's peak
    del big
    with StageMeter(gpu=True) as meter:
        small = torch.empty(16 * 2**20, dtype=torch.uint8, device="cuda")
        torch.cuda.synchronize()
    del small
    assert 16 * 2**20 <= meter.gpu_peak_bytes < 256 * 2**20, meter.gpu_peak_bytes
    assert meter.gpu_s == meter.wall_s > 0
