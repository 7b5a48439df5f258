"""Tables in the docs that the code generates, committed into the Markdown between markers.

A page is read on GitHub as well as on the site, so a table made from the code is written into
the page itself, between

    <!-- generated: NAME (python scripts/update_docs_tables.py rewrites it) -->
    ...
    <!-- end generated: NAME -->

`scripts/update_docs_tables.py` rewrites every block from the code; `tests/docs/test_generated_tables.py`
fails when a committed block differs from what the code generates now, and the site build
(`hooks.py`) warns (an error under `mkdocs build --strict`, as CI builds) and shows the fresh one.
A generator is a `bfields` command (run in process through the console script `pyproject.toml`
declares, with this checkout first on the import path) or a `module:function` returning Markdown.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIX = "python scripts/update_docs_tables.py"

#: Block name -> its generator: a list of `bfields` arguments, or a "module:function".
GENERATORS: dict[str, list[str] | str] = {
    "bfields params --markdown": ["params", "--markdown"],
    "splat formats": "bayesian_fields_core.scene.formats.registry:markdown_table",
    "camera formats": "bayesian_fields_core.scene.camera_formats:markdown_table",
    "trainer layouts": "bayesian_fields_core.scene.trainers:markdown_table",
    "problem types": "bayesian_fields_service.api.problem_types:markdown_sections",
}

_BLOCK = re.compile(
    r"^<!-- generated: (?P<name>[^\n]+?) \(" + re.escape(FIX) + r" rewrites it\) -->\n"
    r"(?P<body>.*?)"
    r"^<!-- end generated: (?P=name) -->$",
    re.S | re.M,
)


def begin_marker(name: str) -> str:
    return f"<!-- generated: {name} ({FIX} rewrites it) -->"


def end_marker(name: str) -> str:
    return f"<!-- end generated: {name} -->"


def _bfields(args: list[str], root: Path) -> str:
    """stdout of `bfields ARGS` run in process; a failure raises."""
    target = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]["bfields"]
    module_name, _, func_name = target.partition(":")
    main = getattr(importlib.import_module(module_name), func_name)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = main(args)
    if status:
        raise RuntimeError(f"`bfields {' '.join(args)}` exited with status {status}")
    return out.getvalue()


def generate(name: str, root: Path = ROOT) -> str:
    """The Markdown block `name` holds when it is current (GitHub's table syntax), ending in a newline."""
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    generator = GENERATORS[name]
    if isinstance(generator, list):
        text = _bfields(generator, root)
    else:
        module_name, _, func_name = generator.partition(":")
        text = getattr(importlib.import_module(module_name), func_name)()
    return text if text.endswith("\n") else text + "\n"


@dataclass(frozen=True)
class Block:
    name: str
    body: str
    start: int
    end: int


def blocks(markdown: str) -> list[Block]:
    """The generated blocks of a page, in order; an unknown name is an error (a typo'd marker
    would otherwise never be refreshed)."""
    found = [Block(m["name"], m["body"], m.start("body"), m.end("body")) for m in _BLOCK.finditer(markdown)]
    for block in found:
        if block.name not in GENERATORS:
            raise ValueError(f"unknown generated block {block.name!r} (known: {', '.join(GENERATORS)})")
    return found


def refresh(markdown: str, root: Path = ROOT) -> str:
    """The page with every generated block rewritten from the code."""
    out, at = [], 0
    for block in blocks(markdown):
        out += [markdown[at : block.start], generate(block.name, root)]
        at = block.end
    return "".join(out) + markdown[at:]


def pages(root: Path = ROOT) -> list[Path]:
    """The docs pages (and README) that hold a generated block."""
    candidates = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    return [p for p in candidates if p.is_file() and "<!-- generated: " in p.read_text(encoding="utf-8")]


def stale(root: Path = ROOT) -> list[tuple[Path, str]]:
    """(page, block name) of every committed block that differs from what the code generates."""
    out = []
    for page in pages(root):
        text = page.read_text(encoding="utf-8")
        out += [(page, b.name) for b in blocks(text) if b.body != generate(b.name, root)]
    return out
