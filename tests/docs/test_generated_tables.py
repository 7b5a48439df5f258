"""The tables the code generates are committed into the docs (so GitHub shows them) and equal to
what the code generates now; the site build shows the same tables with the site's pipes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BUILD = ROOT / "docs" / "_build"


@pytest.fixture(scope="module")
def generated():  # noqa: ANN201 - the docs/_build/generated module
    sys.path.insert(0, str(BUILD))
    try:
        import generated as module
    finally:
        sys.path.remove(str(BUILD))
    return module


def test_every_generated_table_is_committed_and_current(generated) -> None:  # noqa: ANN001
    pages = generated.pages(ROOT)
    held = {block.name: page for page in pages for block in generated.blocks(page.read_text())}
    assert set(held) == set(generated.GENERATORS), f"blocks on the pages: {held}"
    for page in pages:
        for block in generated.blocks(page.read_text()):
            assert block.body.strip(), f"{page.relative_to(ROOT)}: the {block.name!r} block is empty"
            assert block.body == generated.generate(block.name, ROOT), (
                f"{page.relative_to(ROOT)}: the committed {block.name!r} table differs from the code; "
                f"run: {generated.FIX}"
            )


def test_no_page_keeps_a_placeholder_that_only_the_build_fills() -> None:
    """GitHub shows an HTML comment as nothing: a page must not rely on the build to fill one in."""
    for page in [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]:
        for line in page.read_text().splitlines():
            assert line.strip() not in ("<!-- splat formats -->", "<!-- bfields params --markdown -->"), page


def test_the_splat_format_table_is_the_registry(generated) -> None:  # noqa: ANN001
    from bayesian_fields_core.scene.formats.registry import SPLAT_FORMATS, markdown_table

    page = ROOT / "docs" / "guide" / "your-scene.md"
    (block,) = [b for b in generated.blocks(page.read_text()) if b.name == "splat formats"]
    assert block.body == markdown_table()
    rows = [line for line in block.body.splitlines() if line.startswith("| ")][1:]  # header off
    assert [row.split(" | ")[0].removeprefix("| ") for row in rows] == [f.title for f in SPLAT_FORMATS]


def test_update_script_finds_and_rewrites_a_stale_table(tmp_path: Path, generated) -> None:  # noqa: ANN001
    """The fix the failure message names works: on a copy whose table lost a row, `--check` says
    which, and a plain run restores the table."""
    page = ROOT / "docs" / "guide" / "your-scene.md"
    copy = tmp_path / "docs" / "guide" / "your-scene.md"
    copy.parent.mkdir(parents=True)
    text = page.read_text()
    (block,) = [b for b in generated.blocks(text) if b.name == "splat formats"]
    last_row = block.body.splitlines(keepends=True)[-1]
    copy.write_text(text.replace(last_row, "", 1))
    for name in ("pyproject.toml",):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / "bayesian_fields_core").symlink_to(ROOT / "bayesian_fields_core")
    assert generated.stale(tmp_path) == [(copy, "splat formats")]
    assert generated.refresh(copy.read_text(), tmp_path) == text
    check = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "update_docs_tables.py"), "--check"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert check.returncode == 0, check.stdout + check.stderr


def test_the_build_shows_the_tables_with_the_sites_pipes(generated) -> None:  # noqa: ANN001
    """Rendered as the build renders it (a fresh process, `hooks.render`): GitHub's `\\|` inside a
    code span becomes `|` (Python-Markdown splits no cell there), and nothing is warned about."""
    page = ROOT / "docs" / "guide" / "parameters.md"
    script = (
        "import logging, sys; logging.basicConfig(level=logging.WARNING); sys.path.insert(0, sys.argv[1]); "
        "import hooks; sys.stdout.write(hooks.render(open(sys.argv[2]).read()))"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(BUILD), str(page)], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert "out of date" not in done.stderr, done.stderr
    assert "`bayes|average`" in done.stdout and "`bayes\\|average`" in page.read_text()
