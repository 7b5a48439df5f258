"""The splat format table is the one place a format is declared, and everything reads it.

The loader's detection, the layout's "which file is the splat", the upload's name check, the
error messages, the API's OpenAPI description of the upload and the docs' format table all come
from `scene/formats/registry.py`; these tests fail when one of them keeps a list of its own.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fastapi import FastAPI

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats import registry
from bayesian_fields_core.scene.formats.registry import (
    SPLAT_FORMATS,
    SplatFormat,
    accepted_names,
    check_upload_name,
    detect,
    is_splat_candidate,
    markdown_table,
    upload_description,
)
from bayesian_fields_core.scene.layout import find_splat_file

ROOT = Path(__file__).resolve().parents[3]
DOCS = ROOT / "docs"
FORMATS_PAGE = DOCS / "guide" / "your-scene.md"
MARKER = "<!-- generated: splat formats ("


def test_every_row_names_real_functions_and_a_way_in() -> None:
    names = [fmt.name for fmt in SPLAT_FORMATS]
    assert len(names) == len(set(names))
    for fmt in SPLAT_FORMATS:
        assert fmt.suffixes or fmt.file_names, fmt.name
        for field in ("sniff", "source", "reader", "writer"):
            if getattr(fmt, field) is not None:
                assert callable(fmt.function(field)), (fmt.name, field)
    # formats sharing a suffix are told apart by content, with one row taking what is left
    for suffix in {s for fmt in SPLAT_FORMATS for s in fmt.suffixes}:
        sharing = [fmt for fmt in SPLAT_FORMATS if suffix in fmt.suffixes]
        if len(sharing) > 1:
            assert [fmt.sniff is None for fmt in sharing].count(True) == 1, suffix


def test_names_and_content_pick_the_row(tmp_path: Path) -> None:
    from bayesian_fields_core.scene.ply import read_ply, write_ply

    ply = ROOT / "samples" / "tabletop" / "point_cloud.ply"
    assert detect(ply).name == "ply"
    sog = tmp_path / "unzipped"
    sog.mkdir()
    assert detect(sog).name == "sog" and detect(sog / "meta.json").name == "sog"
    write_ply(tmp_path / "copy.PLY", read_ply(ply))
    assert detect(tmp_path / "copy.PLY").name == "ply"
    with pytest.raises(InputError, match=r"\.ksplat splats are not read; convert it first: npx @playcanvas"):
        detect(tmp_path / "scene.ksplat")
    with pytest.raises(InputError, match=r"not a splat format we read \(\.ply, \.spz, .*\.pt\)"):
        detect(tmp_path / "scene.obj")


def test_the_upload_check_follows_the_table() -> None:
    for fmt in SPLAT_FORMATS:
        for suffix in fmt.suffixes:
            if fmt.upload or any(other.upload for other in SPLAT_FORMATS if suffix in other.suffixes):
                check_upload_name(f"scene{suffix.upper()}")
            else:
                with pytest.raises(InputError, match="scene"):
                    check_upload_name(f"scene{suffix}")
    with pytest.raises(InputError, match=r"does not accept checkpoints \(\.pt\).*bfields submit"):
        check_upload_name("ckpt_29999_rank0.pt")
    with pytest.raises(InputError, match="'meta.json' is not a splat file we read"):
        check_upload_name("meta.json")  # one file cannot carry a SOG folder


def test_a_new_row_reaches_every_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What 'one table' promises: a row added here is detected, listed, accepted by the upload
    check, counted by the layout and shown in the docs, with nothing else edited."""
    row = SplatFormat(
        "tiny",
        "a test format",
        suffixes=(".tiny",),
        source="bayesian_fields_core.scene.formats.spz:open_spz",
        notes="only in this test",
    )
    monkeypatch.setattr(registry, "SPLAT_FORMATS", (*SPLAT_FORMATS, row))
    (tmp_path / "scene.tiny").write_bytes(b"\0")
    assert detect(tmp_path / "scene.tiny") is row
    assert ".tiny" in accepted_names(upload=True) and ".tiny" in upload_description()
    check_upload_name("scene.tiny")
    assert is_splat_candidate(tmp_path / "scene.tiny")
    assert find_splat_file(tmp_path) == (tmp_path / "scene.tiny", "plain")
    assert "| a test format | `.tiny` | yes |" in markdown_table()


def test_the_layout_counts_refused_formats_as_splats(tmp_path: Path) -> None:
    """A lone .ksplat is found and then refused naming its converter, never 'no splat found'."""
    (tmp_path / "scene.ksplat").write_bytes(b"\0")
    assert find_splat_file(tmp_path)[0].name == "scene.ksplat"
    (tmp_path / "scene.ksplat").unlink()
    with pytest.raises(InputError, match=r"no splat found .*\(\.ply, \.spz, \.sog, SOG meta\.json"):
        find_splat_file(tmp_path)


def test_the_api_describes_the_upload_from_the_table() -> None:
    from bayesian_fields_service.api.routes import scenes

    app = FastAPI()
    app.include_router(scenes.router)
    form = app.openapi()["paths"]["/v1/scenes"]["post"]["requestBody"]["content"]["multipart/form-data"]
    described = form["schema"]["properties"]["splat"]["description"]
    assert described == upload_description()
    for fmt in SPLAT_FORMATS:
        for suffix in fmt.suffixes:
            assert suffix in described, suffix  # accepted, or named as refused
    assert "not .pt" in described


def test_the_docs_table_is_generated_from_the_table() -> None:
    """The page holds the registry's table (committed between markers, so GitHub shows it;
    `tests/docs/test_generated_tables.py` keeps it current), and the site shows the same rows."""
    page = FORMATS_PAGE.read_text()
    assert page.count(MARKER) == 1
    assert markdown_table() in page
    script = (
        "import sys; sys.path.insert(0, sys.argv[1]); import hooks; "
        "sys.stdout.write(hooks.render(open(sys.argv[2]).read()))"
    )
    rendered = subprocess.run(
        [sys.executable, "-c", script, str(DOCS / "_build"), str(FORMATS_PAGE)],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    ).stdout
    table = markdown_table().replace("\\|", "|")  # the site's tables keep no `\|` (hooks.code_pipes)
    assert table in rendered
    assert len(table.splitlines()) == len(SPLAT_FORMATS) + 2  # header, rule, one row per format
