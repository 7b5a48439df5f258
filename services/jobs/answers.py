"""What a succeeded job's answers are as rows (issue 42), read from its `result/summary.json`.

Per task (in the job's task order), one row per ranked object, rank 1 the best, or one row with
rank 0 and found = false when the task was answered "not found" (or selected nothing). A row
holds the task's text and index, the object's id, content key, probability, best-view score
(`best_view_score`, `peak` before format 1.6), ranking score (`score`, what `ranked_by` names:
the evidence by default), Gaussian count, its box (centre, extents, rotation) and centroid in
the user's world frame, and the key of the task's preview image.

"The user's world frame": the result's outermost frame, the data's own world (`world_frame`,
when nerfstudio's applied transform was undone) else the cameras' (`capture_frame`, when the
loader mapped the splat into it) else the splat file's own; the row's `frame` names which.

Why the summary and not `read_result`: the rows need only the summary (no per-Gaussian array),
so writing them adds one small read to a job's finish; only a result older than format 1.5,
whose selections carry no content key, is read whole for its computed keys (a backfill's case).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from sqlalchemy import Engine

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import Store
from bayesian_fields_core.results.format import SelectedObject
from bayesian_fields_core.results.reader import read_result, read_summary
from bayesian_fields_service.jobs.model import JobRecord, utcnow
from bayesian_fields_service.records import answers as answer_records
from bayesian_fields_service.records.answers import AnswerFilter as AnswerFilter
from bayesian_fields_service.records.answers import FleetAnswers as FleetAnswers
from bayesian_fields_service.storage.stores import tenant_store

log = logging.getLogger(__name__)

RESULT_DIR = "result/"


def _frame(obj: SelectedObject) -> tuple[str, Any, Any]:
    """(frame name, centroid, box) of the object in the user's world frame (module docstring)."""
    if obj.world_box is not None and obj.world_centroid is not None:
        return "world", obj.world_centroid, obj.world_box
    if obj.capture_box is not None and obj.capture_centroid is not None:
        return "capture", obj.capture_centroid, obj.capture_box
    return "splat", obj.centroid, obj.box


def _xyz(prefix: str, values: Any) -> dict[str, float]:
    return {f"{prefix}_{axis}": float(v) for axis, v in zip("xyz", values, strict=True)}


def _previews(summary: dict[str, Any]) -> dict[str, str]:
    """task -> its preview's key relative to the job (`result/previews/task_00.png`)."""
    entries = (summary.get("previews") or {}).get("tasks") or []
    return {
        str(p["task"]): RESULT_DIR + str(p["file"]) for p in entries if isinstance(p, dict) and p.get("file")
    }


def answer_rows(store: Store, job: JobRecord, finished_at: datetime) -> list[dict[str, Any]]:
    """The rows of the job's answers from its result in `store` (the tenant's store). Raises
    InputError when the result cannot be read (no summary, another format)."""
    prefix = job.job_prefix + RESULT_DIR
    summary = read_summary(store, prefix)
    try:
        tasks = [str(t) for t in summary["tasks"]]
        entries = {str(e["task"]): e for e in summary["selections"]}
        selections = {
            t: [SelectedObject.from_dict(o) for o in e.get("objects") or []] for t, e in entries.items()
        }
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{prefix}summary.json: malformed tasks or selections ({exc!r})") from None
    if any(o.key is None for objs in selections.values() for o in objs):  # before format 1.5
        selections = read_result(store, prefix).selections
    previews = _previews(summary)
    ranked_by = str(summary.get("ranked_by", "")) or None
    base = {"job_id": job.id, "tenant": job.tenant, "scene_id": job.scene_id, "finished_at": finished_at}
    rows: list[dict[str, Any]] = []
    for index, task in enumerate(tasks):
        common = {**base, "task": task, "task_index": index, "preview": previews.get(task)}
        objects = selections.get(task) or []
        if not objects:
            why = (entries.get(task) or {}).get("not_found") or {}
            reason = why.get("reason") if isinstance(why, dict) else None
            rows.append(
                {**common, "rank": 0, "found": False, "not_found_reason": reason or "no object selected"}
            )
            continue
        for rank, obj in enumerate(objects, start=1):
            frame, centroid, box = _frame(obj)
            rows.append({
                **common, "rank": rank, "found": True, "object_id": int(obj.object_id),
                "content_key": obj.key, "probability": float(obj.probability),
                "best_view_score": obj.best_view_score, "score": obj.score, "ranked_by": ranked_by,
                "num_gaussians": int(obj.num_gaussians), "frame": frame,
                **_xyz("centre", box.center), **_xyz("extent", box.extents), **_xyz("centroid", centroid),
                "rotation": [[float(v) for v in row] for row in box.rotation],
            })  # fmt: skip
    return rows


def rows_for_finish(store: Store, job: JobRecord, finished_at: datetime) -> list[dict[str, Any]]:
    """`answer_rows` for the success write: a result that cannot be read is logged and indexed as
    nothing (the job still succeeds: its files are what the user asked for; `bfields-service
    index-answers` reports it again). Storage errors propagate: the finish is retried."""
    try:
        return answer_rows(store, job, finished_at)
    except InputError as exc:
        log.warning("answers of %s/%s not indexed: %s", job.tenant, job.id, exc)
        return []


@dataclass
class Backfill:
    """What `index_existing` did: jobs indexed, answer rows written, jobs whose result could not
    be read (listed by id, at most `SHOWN`), and how many were left to index when it started."""

    total: int
    indexed: int = 0
    rows: int = 0
    unreadable: list[str] = field(default_factory=list)

    SHOWN = 20

    def line(self) -> str:
        bad = (
            f", {len(self.unreadable)} unreadable ({', '.join(self.unreadable[: self.SHOWN])})"
            if self.unreadable
            else ""
        )
        return (
            f"indexed {self.indexed} of {self.total} succeeded jobs without answers ({self.rows} rows){bad}"
        )


def index_existing(
    bucket: Store, database: Engine, *, chunk: int = 200, progress: Callable[[Backfill], None] | None = None
) -> Backfill:
    """Answers for every succeeded job that has none (jobs that succeeded before revision 0009):
    each job's summary read from `bucket` (the whole bucket; tenants by prefix) and its rows
    written in a transaction of its own, so a stopped run resumes where it was and a second run
    finds nothing to do. `progress` is called after each chunk."""
    done = Backfill(total=answer_records.count_unindexed(database))
    after = ""
    while batch := answer_records.unindexed_jobs(database, after=after, limit=chunk):
        for tenant, job_id, scene_id, finished_at in batch:
            job = JobRecord.model_construct(id=job_id, tenant=tenant, scene_id=scene_id, tasks=[])
            try:
                rows = answer_rows(tenant_store(bucket, tenant), job, finished_at or utcnow())
            except InputError as exc:
                log.warning("answers of %s/%s not indexed: %s", tenant, job_id, exc)
                done.unreadable.append(job_id)
                continue
            answer_records.write_job(database, job_id, rows)
            done.indexed += 1
            done.rows += len(rows)
        after = batch[-1][1]
        if progress is not None:
            progress(done)
    return done


class Answers:
    """The tenants' answers as the answer routes read them: a batch's rows (a page, or the whole
    table as CSV), one task's answers across the fleet, and the task a part of its text names.

    Why an object and not the routes calling `records.answers`: the routes translate HTTP and call
    a domain, never the records (issue 43); this holds the records engine, so the API's state
    hands the routes this and not the engine. Each method is one indexed statement of
    `records.answers`; the filter and page types are that module's (`AnswerFilter`,
    `FleetAnswers`, re-exported here)."""

    def __init__(self, database: Engine) -> None:
        self._database = database

    def matching_tasks(self, tenant: str, part: str, *, batch_id: str | None = None) -> list[str]:
        """The answered tasks `part` names: its exact text if any answer has it, else the tasks
        whose text contains it (case-insensitive), in the batch `batch_id` or the whole fleet."""
        return answer_records.matching_tasks(self._database, tenant, part, batch_id=batch_id)

    def batch_page(
        self,
        tenant: str,
        batch_id: str,
        wanted: AnswerFilter,
        *,
        after: tuple[int, int, int] | None,
        limit: int,
    ) -> list[dict[str, Any]]:
        """Up to `limit` of the batch's rows kept by `wanted`, after the keyset `after`."""
        return answer_records.batch_page(self._database, tenant, batch_id, wanted, after=after, limit=limit)

    def batch_csv(
        self,
        tenant: str,
        batch_id: str,
        wanted: AnswerFilter,
        *,
        after: tuple[int, int, int] | None,
        jobs_per_page: int,
    ) -> Iterator[bytes]:
        """The batch's rows kept by `wanted` as CSV chunks, `jobs_per_page` jobs per read."""
        return answer_records.batch_csv(
            self._database, tenant, batch_id, wanted, after=after, jobs_per_page=jobs_per_page
        )

    def fleet(
        self,
        tenant: str,
        task: str,
        *,
        batch_ids: Sequence[str] = (),
        min_probability: float | None = None,
        best_only: bool = True,
        after: tuple[float, str, int] | None = None,
        limit: int,
    ) -> FleetAnswers:
        """One task's answers over the tenant's scenes (each one's latest succeeded job that asked it)."""
        return answer_records.fleet(self._database, tenant, task, batch_ids=batch_ids,
                                    min_probability=min_probability, best_only=best_only, after=after,
                                    limit=limit)  # fmt: skip

    def answer_probability(self, tenant: str, task: str, job_id: str, rank: int) -> float | None:
        """The probability of one found answer (a fleet cursor's position), or None when it is gone."""
        return answer_records.answer_probability(self._database, tenant, task, job_id, rank)
