"""MkDocs hooks: output of the code itself, written into pages at build time.

`on_config` links packages whose folder is named otherwise than their import name (see
`package_layout.py`) where mkdocstrings looks for sources.

`<!-- bfields params --markdown -->` on a line of its own is replaced by what that command prints:
the table of every pipeline parameter, generated from `PipelineParams`, so the page cannot drift
from the model. `<!-- splat formats -->` is replaced by the splat format table, generated from
`scene/formats/registry.py` (`markdown_table`), the table the loader and the upload check read;
`<!-- camera formats -->` and `<!-- trainer layouts -->` likewise by the camera format and trainer
layout tables (`scene/camera_formats.py`, `scene/trainers.py`). The command is found through the `bfields` console script declared in
`pyproject.toml` and run in this process, with this checkout first on the import path, so the
build needs no reinstall after modules move.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import re
import sys
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]

# Marker -> the `bfields` arguments whose stdout replaces it.
COMMANDS = {
    "<!-- bfields params --markdown -->": ["params", "--markdown"],
}
# Marker -> the `module:function` (no arguments, returns Markdown) whose result replaces it.
FUNCTIONS = {
    "<!-- splat formats -->": "bayesian_fields_core.scene.formats.registry:markdown_table",
    "<!-- camera formats -->": "bayesian_fields_core.scene.camera_formats:markdown_table",
    "<!-- trainer layouts -->": "bayesian_fields_core.scene.trainers:markdown_table",
}


def bfields(args: list[str], root: Path = ROOT) -> str:
    """stdout of `bfields ARGS` run in process; a failure stops the build."""
    target = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]["bfields"]
    module_name, _, func_name = target.partition(":")
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    main = getattr(importlib.import_module(module_name), func_name)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = main(args)
    if status:
        raise RuntimeError(f"`bfields {' '.join(args)}` exited with status {status}")
    return out.getvalue()


def call(target: str, root: Path = ROOT) -> str:
    """The Markdown a library function returns, imported from this checkout."""
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    module_name, _, func_name = target.partition(":")
    return getattr(importlib.import_module(module_name), func_name)()


def code_pipes(table: str) -> str:
    r"""GitHub's tables need `\|` for a pipe even inside a code span (`bayes\|average`);
    Python-Markdown splits no cell inside a code span and would show the backslash: drop it there."""
    return re.sub(r"`[^`\n]*`", lambda m: m.group(0).replace("\\|", "|"), table)


def render(markdown: str, root: Path = ROOT) -> str:
    """The page with every marker line replaced by its command's or function's output."""
    lines = []
    for line in markdown.splitlines(keepends=True):
        args, target = COMMANDS.get(line.strip()), FUNCTIONS.get(line.strip())
        if args:
            line = code_pipes(bfields(args, root))
        elif target:
            line = code_pipes(call(target, root))
        lines.append(line)
    return "".join(lines)


def on_config(config: Any) -> Any:
    """Let griffe find, statically, a package installed under another name than its folder's."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from package_layout import link_import_names

    link_import_names(ROOT)
    return config


def on_page_markdown(markdown: str, **_: object) -> str:
    return render(markdown)
