"""Compile every numba kernel of the cluster stage once, so later processes load them from the
cache: `python -m bayesian_fields_core.objects.compile_kernels` (the worker images run it at
build time; on a developer machine the first cluster stage does it through `prepare_kernels`,
saying so, since it takes seconds)."""

from __future__ import annotations

import logging
import time

import numpy as np

from bayesian_fields_core.compute.jit import KERNELS, is_cached
from bayesian_fields_core.geometry.obb import minimum_obb
from bayesian_fields_core.objects.aib import aib
from bayesian_fields_core.objects.edges import merge_identical, overlap_edges
from bayesian_fields_core.objects.primitives import PrimitiveBuilder
from bayesian_fields_core.objects.probabilities import primitive_means

log = logging.getLogger(__name__)


def compile_kernels() -> float:
    """Run each compiled kernel on a tiny graph; returns the seconds it took."""
    start = time.perf_counter()
    means = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5], [1.5, 1.5, 1.5]])
    primitive_ids = np.array([0, 0, 1, 1])
    edges = overlap_edges(means, primitive_ids)  # the box sweep
    overlap_edges(means.astype(np.float32), primitive_ids)  # scene centres are float32
    pyx = np.array([[0.2, 0.8], [0.6, 0.4]])
    graph = merge_identical(pyx, edges)  # the identical-row test
    aib(graph.pyx, graph.edges, delta=1.0, weights=graph.weights)  # the greedy merge loop
    minimum_obb(np.random.default_rng(0).normal(size=(80, 3)))  # the box search
    primitive_means(np.array([0, 0, 1]), [np.zeros((3, 2), np.float32)])  # the fused state is float32
    builder = PrimitiveBuilder(4)  # the primitive rule, for the id types fuse and the caches use
    for gaussian_type, mask_type in ((np.int64, np.int64), (np.uint32, np.int32), (np.int64, np.int32)):
        builder.add_frame(np.arange(2, dtype=gaussian_type), np.zeros(2, dtype=mask_type), np.ones(1, bool))
    return time.perf_counter() - start


def kernels_cached() -> bool | None:
    """Whether every numba kernel loads without compiling (None: numba cannot tell us)."""
    states = [is_cached(k) for k in KERNELS]
    if False in states:
        return False
    return None if None in states else True


def prepare_kernels() -> float:
    """Compile the kernels now when they are not cached, announcing it (it takes seconds and
    happens once per machine); logs the cache hit otherwise. Returns the seconds spent."""
    cached = kernels_cached()
    if cached is not False:
        log.debug("numba kernels: %s", "cache hit" if cached else "cache state unknown")
        return 0.0
    log.info("compiling kernels (first run only, ~10 s)")
    seconds = compile_kernels()
    log.debug("numba kernels: cache miss, compiled in %.1f s", seconds)
    return seconds


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    print(f"numba kernels ready in {prepare_kernels():.1f} s")
