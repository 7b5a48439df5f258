"""MkDocs hooks: output of the code itself, kept in the pages.

`on_config` links packages whose folder is named otherwise than their import name (see
`package_layout.py`) where mkdocstrings looks for sources.

The tables the code generates (every pipeline parameter from `PipelineParams`, through
`bfields params --markdown`; the splat formats from `scene/formats/registry.py`'s
`markdown_table`) are committed into their pages between markers, so GitHub shows them too
(`generated.py`). At build time each block is regenerated: a committed block that differs is
reported as a warning naming the fix (`python scripts/update_docs_tables.py`), which CI's strict
build turns into an error, and the page shows the fresh table either way.
"""

from __future__ import annotations

import logging
import re
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generated  # noqa: E402 - beside this file, found through the line above

ROOT = generated.ROOT
log = logging.getLogger("mkdocs.hooks.generated")


def code_pipes(table: str) -> str:
    r"""GitHub's tables need `\|` for a pipe even inside a code span (`bayes\|average`);
    Python-Markdown splits no cell inside a code span and would show the backslash: drop it there."""
    return re.sub(r"`[^`\n]*`", lambda m: m.group(0).replace("\\|", "|"), table)


def render(markdown: str, root: Path = ROOT, where: str = "a page") -> str:
    """The page as the site shows it: every generated block fresh from the code (a stale one
    warned about), with the site's pipes."""
    out, at = [], 0
    for block in generated.blocks(markdown):
        fresh = generated.generate(block.name, root)
        if block.body != fresh:
            log.warning(
                "%s: the generated %r table is out of date with the code; run: %s",
                where, block.name, generated.FIX,
            )  # fmt: skip
        out += [markdown[at : block.start], code_pipes(fresh)]
        at = block.end
    return "".join(out) + markdown[at:]


def on_config(config: Any) -> Any:
    """Let griffe find, statically, a package installed under another name than its folder's."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from package_layout import link_import_names

    link_import_names(ROOT)
    return config


def on_page_markdown(markdown: str, page: Any = None, **_: object) -> str:
    where = getattr(getattr(page, "file", None), "src_path", "a page")
    return render(markdown, where=f"docs/{where}")
