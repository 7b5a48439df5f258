"""The alignment check's verdict, cached like perception: a warm re-run does not render it again.

The check (`checks/alignment.py`) renders a few frames and reads their photos; on a busy machine
that was half of a cached re-run. Its report is a pure function of the content
`stage_table.ALIGNMENT_CACHE` declares (splat with colours, cameras, the compared photos, the
check's parameters and code), so it is stored under that content's digest in the job's cache
root, beside the perception frames, and recorded in the cache index (stage ``alignment``): `bfields
cache ls` counts it and `prune` drops it with its scene's entry. A failed verdict is cached too:
the same inputs fail the same way, and changing any of them (a transform, a camera, a parameter)
makes a new key.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from pydantic import ValidationError

from bayesian_fields_core.checks.alignment import assess_alignment
from bayesian_fields_core.checks.alignment_reports import AlignmentReport
from bayesian_fields_core.job.store import ArtifactNotFound

if TYPE_CHECKING:
    from bayesian_fields_core.job.context import JobContext

log = logging.getLogger(__name__)


def cached_alignment(ctx: JobContext) -> AlignmentReport:
    """The scene's alignment report, from the cache when these inputs were checked before
    (`cached` is then true), else computed and stored. Does not raise on a failed verdict."""
    store = ctx.scene_store
    assert store is not None
    key = ctx.keys.alignment_key()
    ctx.record_cache_use("alignment", [key])  # before computing: protects the entry from a prune
    try:
        report = AlignmentReport.model_validate_json(store.get_bytes(key))
    except ArtifactNotFound:
        log.debug("alignment cache: miss %s", key)
    except ValidationError:
        log.debug("alignment cache: unreadable %s, checking again", key)
    else:
        log.debug("alignment cache: hit %s", key)
        return report.model_copy(update={"cached": True})
    device = ctx.params.device or ctx.models.render_device
    report = assess_alignment(ctx.scene(), ctx.params, device=device)
    store.put_bytes(key, report.model_dump_json().encode())
    return report
