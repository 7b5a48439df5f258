"""The result format: per-Gaussian object ids, the object probability table, the summary with each
task's top-k objects, and optional splat exports. See `docs/results-format.md`."""

from bayesian_fields_core.results.format import FORMAT_VERSION, NotFound, Result, SelectedObject
from bayesian_fields_core.results.reader import object_gaussians, read_result, read_summary, result_sizes
from bayesian_fields_core.results.writer import write_result

__all__ = [
    "FORMAT_VERSION",
    "NotFound",
    "Result",
    "SelectedObject",
    "object_gaussians",
    "read_result",
    "read_summary",
    "result_sizes",
    "write_result",
]
