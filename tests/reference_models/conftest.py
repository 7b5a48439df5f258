"""The reference-architecture models, built once per session (or read from a prepared folder).

These tests need the second venv (scripts/make_reference_venv.sh: torch 2.14.1 + torchvision,
ultralytics, open_clip); in the project venv they are skipped with that reason. The models are
those of scripts/make_reference_models.py: from `BFIELDS_REFERENCE_MODELS` when it names a
folder that script wrote (the CI stage builds it once), else built here into a temp folder.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# Modules the second venv has and the project venv lacks; the tests skip when any is missing.
MISSING = [
    m
    for m in ("ultralytics", "open_clip", "torchvision", "onnxruntime")
    if importlib.util.find_spec(m) is None
]


@pytest.fixture(scope="session")
def reference_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    given = os.environ.get("BFIELDS_REFERENCE_MODELS")
    if given and (Path(given) / "profiles").is_dir():
        return Path(given)
    sys.path.insert(0, str(ROOT / "scripts"))
    import make_reference_models

    out = tmp_path_factory.mktemp("reference-models")
    assert make_reference_models.main(["--out", str(out)]) == 0
    return out


@pytest.fixture(autouse=True)
def _home_in_tmp(tmp_home: Path) -> None:
    """Every reference-model test: ultralytics settings and HF caches write inside tmp."""
