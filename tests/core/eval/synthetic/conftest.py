"""A small synthetic scene generated once per session (a few seconds on CPU)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.eval.synthetic import SceneSpec, generate_scene

SMALL = SceneSpec(
    name="test-small",
    seed=5,
    n_objects=7,
    n_duplicates=1,
    n_colours=4,
    n_groups=2,
    object_density=8000.0,
    table_density=1000.0,
    room_density=150.0,
    width=96,
    height=72,
    n_frames=4,
)


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_scene(tmp_path_factory.mktemp("synthetic") / "scene", SMALL)
