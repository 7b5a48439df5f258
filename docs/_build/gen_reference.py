"""Generate the API reference pages at build time (mkdocs-gen-files).

The package tree is walked as it is on disk, so a module that moves, appears or goes away changes
the reference on the next build with no list to keep. Which packages to walk, and under which
import names, is read from `pyproject.toml` (the same declaration pip installs from), so the
`services/` folder shows up under whatever name it is installed as. One page per module holds a
single mkdocstrings directive (`::: package.module`); griffe reads the docstrings from the source
without importing anything, so torch, numba or the service's clients need not import here.
"""

from __future__ import annotations

import sys
from pathlib import Path

import mkdocs_gen_files

sys.path.insert(0, str(Path(__file__).resolve().parent))
from package_layout import top_level_packages  # noqa: E402 (a sibling module, not an installed one)

OVERVIEW = """# API reference

Generated from the docstrings of the code this site was built from: one page per module, found by
walking the package folders at build time, so it lists the modules as they are in this version.
The layers and what each package is for: [Architecture](../development/architecture.md).

"""


def modules(name: str, folder: Path) -> list[tuple[tuple[str, ...], bool]]:
    """(dotted parts, is a package) of every module of one package, a package before its
    modules; private modules (`_name.py`), `__main__` and folders without `__init__.py` are left
    out."""
    found = []
    for path in folder.rglob("*.py"):
        parts = path.relative_to(folder).with_suffix("").parts
        if any(p.startswith("_") and p != "__init__" for p in parts):
            continue
        if not all((folder.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(len(parts))):
            continue  # a script folder inside the package tree, not importable
        is_package = parts[-1] == "__init__"
        found.append(((name, *parts[:-1]) if is_package else (name, *parts), is_package))
    return sorted(found)


def main() -> None:
    nav = mkdocs_gen_files.Nav()
    packages = top_level_packages()
    if not packages:
        raise SystemExit("gen_reference: no package found in pyproject.toml")
    for name, folder in packages.items():
        for parts, is_package in modules(name, folder):
            # A package is its folder's index page (a section page in the nav), a module a page.
            doc_path = Path(*parts, "index.md") if is_package else Path(*parts).with_suffix(".md")
            nav[parts] = doc_path.as_posix()
            with mkdocs_gen_files.open(Path("reference") / doc_path, "w") as fd:
                fd.write(f"::: {'.'.join(parts)}\n")
    with mkdocs_gen_files.open("reference/index.md", "w") as fd:
        fd.write(OVERVIEW)
        for name in packages:
            fd.write(f"- [`{name}`]({name}/index.md)\n")
    with mkdocs_gen_files.open("reference/SUMMARY.md", "w") as fd:
        fd.write("* [Overview](index.md)\n")
        fd.writelines(nav.build_literate_nav())


main()
