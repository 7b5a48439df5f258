"""The algorithm lives in the library packages; `stages/` only orchestrates and stores.

Read from the sources (every import statement, at any depth of a module, relative ones
resolved), so a late import inside a function counts as much as one at the top.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import bayesian_fields_core

PACKAGE = Path(bayesian_fields_core.__file__).parent


def imported_modules(path: Path) -> set[str]:
    """Absolute names of the modules that `path` imports."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")
            if node.level:
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names.add(target)
            names.update(f"{target}.{a.name}" for a in node.names)  # `from .. import stages`
    return names


@pytest.mark.parametrize("library", ["objects", "fusion", "eval"])
def test_library_packages_import_nothing_from_stages(library: str) -> None:
    offenders = {
        str(path.relative_to(PACKAGE.parent)): sorted(
            n for n in imported_modules(path) if n.startswith("bayesian_fields_core.stages")
        )
        for path in sorted((PACKAGE / library).rglob("*.py"))
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_the_reader_resolves_relative_imports() -> None:
    names = imported_modules(PACKAGE / "stages" / "cluster.py")
    assert "bayesian_fields_core.objects.clustering" in names
    assert "bayesian_fields_core.stages.markers" in names
