"""The distribution's top-level import packages and their folders, as `pyproject.toml` declares
them, for the build helpers beside this file (read, never hard-coded, so moves need no edit)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# Links named after import packages whose folder has another name (mkdocs.yml lists this folder
# in mkdocstrings' `paths`, so griffe finds such a package statically, without importing it).
IMPORT_NAMES = ROOT / "build" / "docs-import-names"


def top_level_packages(root: Path = ROOT) -> dict[str, Path]:
    """{import name: folder} of the distribution's top-level packages.

    Reads `[tool.setuptools] packages` (an explicit list) or `packages.find.include` (patterns
    such as `pkg*`), and `package-dir` (an import name installed from another folder)."""
    setuptools = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    package_dir = {name: folder for name, folder in setuptools.get("package-dir", {}).items() if name}
    declared = setuptools.get("packages", [])
    if isinstance(declared, dict):  # `packages = {find = {...}}`, or the `[...packages.find]` table
        declared = declared.get("find", {}).get("include", [])
    names = {entry.rstrip("*").rstrip(".").split(".")[0] for entry in declared}
    found = {}
    for name in sorted(n for n in names if n):
        folder = root / package_dir.get(name, name)
        if (folder / "__init__.py").is_file():
            found[name] = folder
    return found


def link_import_names(root: Path = ROOT, links: Path = IMPORT_NAMES) -> dict[str, Path]:
    """Make `links/<import name>` point at the folder of each package whose folder is named
    otherwise (`bayesian_fields_service` -> `services/`); returns {import name: link}."""
    links.mkdir(parents=True, exist_ok=True)
    for old in links.iterdir():
        if old.is_symlink():
            old.unlink()
    made = {}
    for name, folder in top_level_packages(root).items():
        if folder.name != name:
            (links / name).symlink_to(folder, target_is_directory=True)
            made[name] = links / name
    return made
