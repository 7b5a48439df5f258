"""The result format: per-Gaussian object ids, the object probability table, the summary with each
task's top-k objects, and optional splat exports. See `docs/results-format.md`.

Importing this package loads only the reader (the standard library and numpy: a robot-side
process that reads the id map and the tables pays no torch or scipy import). The writer, the
previews and the splat exports load on first use: `write_result` here resolves lazily, and
`results.writer`, `results.previews`, `results.export` and `results.splat_export` import as usual.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bayesian_fields_core.results.format import FORMAT_VERSION, NotFound, Result, SelectedObject
from bayesian_fields_core.results.keys import object_keys
from bayesian_fields_core.results.reader import object_gaussians, read_result, read_summary, result_sizes

if TYPE_CHECKING:
    from bayesian_fields_core.results.writer import write_result

__all__ = [
    "FORMAT_VERSION",
    "NotFound",
    "Result",
    "SelectedObject",
    "object_gaussians",
    "object_keys",
    "read_result",
    "read_summary",
    "result_sizes",
    "write_result",
]


def __getattr__(name: str) -> Any:
    """`write_result` on first use (PEP 562): the writer imports the renderer for its previews."""
    if name == "write_result":
        from bayesian_fields_core.results.writer import write_result

        return write_result
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
