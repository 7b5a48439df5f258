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
from collections.abc import Callable

from pydantic import ValidationError

from bayesian_fields_core.checks.alignment_reports import AlignmentReport
from bayesian_fields_core.job.store import ArtifactNotFound, Store

log = logging.getLogger(__name__)


def cached_alignment(store: Store, key: str, compute: Callable[[], AlignmentReport]) -> AlignmentReport:
    """The report stored under `key` (`cached` is then true), else `compute()`'s, stored there.
    `key` is `CacheKeys.alignment_key`; the caller records it in the cache index first, so a
    concurrent prune keeps it. Does not raise on a failed verdict."""
    try:
        report = AlignmentReport.model_validate_json(store.get_bytes(key))
    except ArtifactNotFound:
        log.debug("alignment cache: miss %s", key)
    except ValidationError:
        log.debug("alignment cache: unreadable %s, checking again", key)
    else:
        log.debug("alignment cache: hit %s", key)
        return report.model_copy(update={"cached": True})
    report = compute()
    store.put_bytes(key, report.model_dump_json().encode())
    return report
