"""The per-task and per-object .ply exports written through the store are byte for byte the files
`write_ply` writes for the same splats (the exports lay the rows out once and rewrite only the
colour columns per task)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_core.results.export import put_ply, put_task_plys, task_recolour
from bayesian_fields_core.scene.ply import write_ply
from bayesian_fields_core.scene.types import Gaussians


def _splat(n: int, degree_terms: int, rng: np.random.Generator) -> Gaussians:
    return Gaussians(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.normal(-4, 0.5, (n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        sh=rng.normal(0, 0.3, (n, degree_terms, 3)).astype(np.float32),
    )


def test_task_and_object_exports_equal_write_ply(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    splat = _splat(500, 16, rng)
    ids = rng.integers(-1, 12, 500)
    selections = [[3, 7, 1], [], [7], [11, 0, 5, 2, 9, 4]]
    store = LocalStore(tmp_path / "store")
    keys = [f"tasks/task_{t}.ply" for t in range(len(selections))]
    sizes = put_task_plys(store, keys, splat, ids, selections)
    for key, size, chosen in zip(keys, sizes, selections, strict=True):
        reference = tmp_path / "reference.ply"
        write_ply(reference, task_recolour(splat, ids, chosen))
        assert store.get_bytes(key) == reference.read_bytes()
        assert size == reference.stat().st_size
    sizes_one = put_ply(store, "object.ply", splat.subset(ids == 7))
    write_ply(tmp_path / "object.ply", splat.subset(ids == 7))
    assert store.get_bytes("object.ply") == (tmp_path / "object.ply").read_bytes()
    assert sizes_one == (tmp_path / "object.ply").stat().st_size
