"""No module uses another package's private names.

A leading underscore says "this may change without notice; only my neighbours rely on it". A
module that reaches into another package's underscored name couples itself to that package's
insides, and the next refactor there breaks it far away (`cli/main.py` once imported the
synthetic suite's private `_parser`). So this test walks the syntax tree of every module in
`bayesian_fields_core`, `services` (imported as `bayesian_fields_service`), `bench` and
`scripts`, and refuses both shapes of such a use:

- ``from X import _name`` (absolute or relative), and
- ``m._name`` where ``m`` is bound by ``import X as m`` or ``from P import m`` to a module.

"Another package", precisely: the *package of a module* is the dotted name of the folder that
holds it (`bayesian_fields_core.objects` for `bayesian_fields_core/objects/clustering.py`; a
package's `__init__.py` belongs to that package itself). For `bench/` and `scripts/`, which are
folders of scripts and not packages, the folder is the package and a sibling script imported by
its bare name (`import bench_scale`) is in it. A private name is a name with one leading
underscore (dunders such as `__version__` are public). A use is refused when the module that
defines the name is in a different package from the module that uses it; a sub-package is a
different package (`objects.sub` may not use `objects._x`, nor the reverse). Names only the
tests use are not checked here: a test reaching into what it tests is fine.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES: dict[str, str] = {
    "bayesian_fields_core": "bayesian_fields_core",
    "services": "bayesian_fields_service",
}
"""Folder -> the import name of the package it holds (pyproject.toml maps `services/`)."""
SCRIPT_FOLDERS = ("bench", "scripts")


@dataclass(frozen=True)
class Module:
    """One source file: its dotted name and the package (dotted) it belongs to."""

    path: Path
    name: str
    package: str


def modules() -> list[Module]:
    """Every checked source file, named as it is imported."""
    found = []
    for folder, import_name in PACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = [import_name, *path.relative_to(ROOT / folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
                found.append(Module(path, ".".join(parts), ".".join(parts)))
            else:
                found.append(Module(path, ".".join(parts), ".".join(parts[:-1])))
    for folder in SCRIPT_FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            found.append(Module(path, f"{folder}.{path.stem}", folder))
    return found


def package_of(module_name: str, user: Module, known: dict[str, Module]) -> str | None:
    """The package of the module `module_name` names, seen from `user`; None when it is not one
    of ours (a third-party or standard module: their private names are their business, and
    ruff's own rules cover what matters there)."""
    if module_name in known:
        return known[module_name].package
    if user.package in SCRIPT_FOLDERS and f"{user.package}.{module_name}" in known:
        return user.package  # a sibling script imported by its bare name
    return None


def absolute(node: ast.ImportFrom, user: Module) -> str:
    """The absolute module name of a (possibly relative) `from ... import`."""
    if not node.level:
        return node.module or ""
    base = user.package.split(".")
    if node.level > 1:
        base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def violations(user: Module, known: dict[str, Module]) -> list[str]:
    """Every use in `user` of another package's private name, as `path:line: what`."""
    tree = ast.parse(user.path.read_text(), filename=str(user.path))
    where = user.path.relative_to(ROOT) if user.path.is_relative_to(ROOT) else user.path
    found: list[str] = []
    module_aliases: dict[str, str] = {}  # local name -> module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname:
                    module_aliases[alias.asname] = alias.name
                else:
                    module_aliases[alias.name.split(".")[0]] = alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            source = absolute(node, user)
            for alias in node.names:
                submodule = f"{source}.{alias.name}"
                if submodule in known:
                    module_aliases[alias.asname or alias.name] = submodule
                elif is_private(alias.name):
                    package = package_of(source, user, known)
                    if package is not None and package != user.package:
                        found.append(f"{where}:{node.lineno}: from {source} import {alias.name}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and is_private(node.attr) and isinstance(node.value, ast.Name):
            target = module_aliases.get(node.value.id)
            if target is None:
                continue
            package = package_of(target, user, known)
            if package is not None and package != user.package:
                found.append(f"{where}:{node.lineno}: {node.value.id}.{node.attr} ({target})")
    return found


@pytest.mark.slow
def test_no_module_uses_another_packages_private_names() -> None:
    everything = modules()
    known = {m.name: m for m in everything}
    found = [line for m in everything for line in violations(m, known)]
    assert found == [], "make the name public where it is defined, or move the user:\n" + "\n".join(found)


def test_the_check_sees_both_shapes(tmp_path: Path) -> None:
    """The walk finds a private import and a private attribute across packages, and allows both
    inside a package: a check that found nothing because it looked at nothing would pass above."""
    user = tmp_path / "user.py"
    user.write_text(
        "from bayesian_fields_core.objects.clustering import _counts\n"
        "from bayesian_fields_core.objects import clustering\n"
        "clustering._with_null_column\n"
        "from bayesian_fields_core.objects.clustering import objects_from_primitives\n"
    )
    known = {m.name: m for m in modules()}
    outside = Module(user, "bayesian_fields_core.stages.user", "bayesian_fields_core.stages")
    inside = Module(user, "bayesian_fields_core.objects.user", "bayesian_fields_core.objects")
    assert [line.split(": ", 1)[1] for line in violations(outside, known)] == [
        "from bayesian_fields_core.objects.clustering import _counts",
        "clustering._with_null_column (bayesian_fields_core.objects.clustering)",
    ]
    assert violations(inside, known) == []
