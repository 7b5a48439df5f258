"""The camera format and trainer layout tables decide, and nothing branches on their names.

`scene/camera_formats.py` and `scene/trainers.py` are read by the layout detection, the loader
and the docs; these tests check the tables' search order against real folders, that the layout
code no longer compares camera kinds by string, and that the docs' tables are generated from them.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene import camera_formats, trainers
from bayesian_fields_core.scene.camera_formats import CAMERA_FORMATS, camera_format_named, detect
from bayesian_fields_core.scene.layout import CAMERA_SOURCES, find_camera_file
from bayesian_fields_core.scene.trainers import TRAINER_LAYOUTS, layout_row, run_config_names

ROOT = Path(__file__).resolve().parents[3]
DOCS = ROOT / "docs"
PAGE = DOCS / "guide" / "your-scene.md"
SCENE = ROOT / "bayesian_fields_core" / "scene"


def _make(fmt: camera_formats.CameraFormat, path: Path) -> None:
    """Put `fmt` at `path`: its file, or a folder with its first model file."""
    if fmt.folder:
        path.mkdir(parents=True, exist_ok=True)
        (path / fmt.model_files[0]).write_text("")
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("{}")


def test_the_rows_have_unique_names_and_locations() -> None:
    names = [fmt.name for fmt in CAMERA_FORMATS]
    assert len(set(names)) == len(names)
    assert len(set(CAMERA_SOURCES)) == len(CAMERA_SOURCES)
    layouts = [row.name for row in TRAINER_LAYOUTS]
    assert len(set(layouts)) == len(layouts)
    assert {fmt.trainer for fmt in CAMERA_FORMATS if fmt.trainer} <= set(layouts)


@pytest.mark.parametrize("location", CAMERA_SOURCES)
def test_every_location_is_found_alone(tmp_path: Path, location: str) -> None:
    fmt = next(f for f in CAMERA_FORMATS if location in f.locations)
    _make(fmt, tmp_path / location)
    assert find_camera_file(tmp_path) == (fmt.name, tmp_path / location)


def test_the_search_follows_table_order(tmp_path: Path) -> None:
    """With every location present, each one found in turn as the earlier ones are removed."""
    for fmt in CAMERA_FORMATS:
        for location in fmt.locations:
            _make(fmt, tmp_path / location)
    for location in CAMERA_SOURCES:
        kind, path = find_camera_file(tmp_path)
        assert path == tmp_path / location
        fmt = camera_format_named(kind)
        (path / fmt.model_files[0]).unlink() if fmt.folder else path.unlink()
    with pytest.raises(InputError, match=r"no cameras found \(transforms\.json, sparse/0/"):
        find_camera_file(tmp_path)


def test_a_named_camera_path_is_detected_by_name_then_suffix(tmp_path: Path) -> None:
    _make(camera_format_named("colmap"), tmp_path / "model")
    assert detect(tmp_path / "model").name == "colmap"
    assert detect(tmp_path / "cameras.json").name == "inria"
    assert detect(tmp_path / "poses.json").name == "transforms"
    with pytest.raises(InputError, match=r"cameras must be a transforms\.json, a cameras\.json or a COLMAP"):
        detect(tmp_path / "poses.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"camera folder has no COLMAP model \(images\.bin / images\.txt\)"):
        detect(tmp_path / "empty")


def test_a_folder_gets_the_first_layout_whose_files_it_holds(tmp_path: Path) -> None:
    assert layout_row(tmp_path).name == "plain"
    (tmp_path / "config.yml").write_text("")
    assert layout_row(tmp_path).name == "plain"  # a nerfstudio run needs its dataparser transform too
    (tmp_path / "dataparser_transforms.json").write_text("")
    assert layout_row(tmp_path).name == "nerfstudio"
    (tmp_path / "cfg.yml").write_text("")
    assert layout_row(tmp_path).name == "gsplat"
    (tmp_path / "scene.yaml").write_text("")
    assert layout_row(tmp_path).name == "scene.yaml"
    assert run_config_names() == ("cfg.yml", "config.yml")


def _camera_kind_comparisons(path: Path, names: set[str]) -> list[str]:
    """`x == 'colmap'`-like comparisons: a branch on a camera format's name."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Compare):
            for operand in (node.left, *node.comparators):
                if isinstance(operand, ast.Constant) and operand.value in names:
                    found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_the_layout_code_branches_on_no_camera_format_name() -> None:
    names = {fmt.name for fmt in CAMERA_FORMATS}
    found = [
        line
        for module in ("layout.py", "loader.py", "trainer_runs.py")
        for line in _camera_kind_comparisons(SCENE / module, names)
    ]
    assert found == [], "read the row's field (camera_formats.CAMERA_FORMATS) instead:\n" + "\n".join(found)
    # the walk sees such a comparison where there is one
    probe = SCENE.parent.parent / "tests" / "core" / "scene" / "trainer_layouts.py"
    assert _camera_kind_comparisons(probe, names)


def _rendered_page() -> str:
    script = (
        "import sys; sys.path.insert(0, sys.argv[1]); import hooks; "
        "sys.stdout.write(hooks.render(open(sys.argv[2]).read()))"
    )
    return subprocess.run(
        [sys.executable, "-c", script, str(DOCS / "_build"), str(PAGE)],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    ).stdout


def test_the_docs_tables_are_generated_from_the_tables() -> None:
    page = PAGE.read_text()
    lines = [line.strip() for line in page.splitlines()]
    for name in ("camera formats", "trainer layouts"):  # committed blocks (`docs/_build/generated.py`)
        assert sum(line.startswith(f"<!-- generated: {name} (") for line in lines) == 1, name
        assert lines.count(f"<!-- end generated: {name} -->") == 1, name
    rendered = _rendered_page()
    for table, rows in (
        (camera_formats.markdown_table(), CAMERA_FORMATS),
        (trainers.markdown_table(), TRAINER_LAYOUTS),
    ):
        assert table.replace("\\|", "|") in rendered
        assert len(table.splitlines()) == len(rows) + 2  # header, rule, one row per row
    headings = {line[3:] for line in lines if line.startswith("## ")}
    missing = [row.name for row in TRAINER_LAYOUTS if row.heading and row.heading not in headings]
    assert missing == [], f"trainers.py names sections your-scene.md lacks: {missing}"
