"""Lazy imports of optional extras, with an error that says which extra to install.

FastSAM (ultralytics, AGPL) and open_clip pull torchvision and are not core dependencies; the
modules that use them import them only when such a model is actually built.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from bayesian_fields_core.errors import ModelError


def import_extra(module: str, extra: str, what: str) -> ModuleType:
    """``importlib.import_module(module)`` or a ModelError naming the pip extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ModelError(
            f"{what} needs the optional '{module}' package: install the '{extra}' extra "
            f"(pip install 'bayesian-fields[{extra}]'); import failed: {exc}"
        ) from exc
