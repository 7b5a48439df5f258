"""In-memory fakes of the jobs domain's two ports (`jobs.ports.JobRecords`, `jobs.ports.LiveJobs`),
the way procrastinate's InMemoryConnector stands in for PostgreSQL: dicts, with the semantics the
domain relies on and nothing more.

What they keep: a unit of work commits at the end of its block and leaves nothing behind when the
block raises (the dicts are copied in and swapped on success); unique keys are enforced (a job id
inserted twice raises, an outbox event id and a usage entry id are written once, an
Idempotency-Key keeps its first target unless replaced); batch counts are recounted from the jobs
(what the triggers keep in PostgreSQL) and a batch is marked finished once per finish. Row locks
are no-ops (one thread). What they leave out: SQL, the queue's dispatch statements, scene rows
beyond ready / not ready.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from bayesian_fields_service.jobs.ports import EndRow, JobTx
from bayesian_fields_service.records.tables import ACTIVE_JOB_STATES, JOB_STATES
from bayesian_fields_service.scenes.refusals import SceneGone, SceneNotReady


class DuplicateKey(Exception):
    """A unique key inserted twice (PostgreSQL's IntegrityError)."""


@dataclass
class Tables:
    """The rows the jobs domain touches, by primary key."""

    jobs: dict[str, dict[str, Any]] = field(default_factory=dict)
    keys: dict[tuple[str, str, str], tuple[str, str]] = field(default_factory=dict)
    batches: dict[str, dict[str, Any]] = field(default_factory=dict)
    links: dict[str, list[str]] = field(default_factory=dict)  # batch id -> job ids by position
    outbox: dict[str, tuple[str, str, dict[str, Any]]] = field(default_factory=dict)  # event id ->
    usage: dict[str, EndRow] = field(default_factory=dict)  # entry id -> row
    answers: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    scenes: dict[tuple[str, str], str] = field(default_factory=dict)  # (tenant, scene) -> state
    dispatched: set[str] = field(default_factory=set)


def _now() -> datetime:
    return datetime.now(UTC)


class FakeTx:
    """`JobTx` over `Tables` (in-place: `FakeJobRecords.write` hands it a copy)."""

    def __init__(self, t: Tables) -> None:
        self.t = t

    def load_job(self, tenant: str, job_id: str, *, lock: bool = False) -> Mapping[str, Any] | None:
        row = self.t.jobs.get(job_id)
        return dict(row) if row is not None and row["tenant"] == tenant else None

    def load_jobs(self, tenant: str, job_ids: Sequence[str]) -> list[Mapping[str, Any]]:
        return [r for j in job_ids if (r := self.load_job(tenant, j)) is not None]

    def insert_job(self, row: dict[str, Any]) -> None:
        if row["id"] in self.t.jobs:
            raise DuplicateKey(f"jobs.id {row['id']}")
        self.t.jobs[row["id"]] = dict(row)

    def write_job(self, row: dict[str, Any]) -> None:
        self.t.jobs[row["id"]] = dict(row)

    def insert_jobs(self, rows: list[dict[str, Any]]) -> None:
        for row in rows:
            self.insert_job(row)

    def page_jobs(self, tenant: str, *, states: Sequence[str] | None, scene_id: str | None,
                  batch_id: str | None, before: str | None, limit: int) -> list[Mapping[str, Any]]:  # fmt: skip
        rows = sorted(
            (r for r in self.t.jobs.values() if r["tenant"] == tenant), key=lambda r: r["id"], reverse=True
        )
        rows = [r for r in rows if (states is None or r["state"] in states)
                and (scene_id is None or r["scene_id"] == scene_id)
                and (batch_id is None or r["batch_id"] == batch_id) and (before is None or r["id"] < before)]  # fmt: skip
        return [dict(r) for r in rows[:limit]]

    def count_active(self, tenant: str | None) -> int:
        return len([r for r in self.t.jobs.values() if r["state"] in ACTIVE_JOB_STATES
                    and (tenant is None or r["tenant"] == tenant)])  # fmt: skip

    def active_pairs(self) -> list[tuple[str, str]]:
        return sorted((r["tenant"], r["id"]) for r in self.t.jobs.values() if r["state"] in ACTIVE_JOB_STATES)

    def admission_count(self, tenant: str) -> int:
        return self.count_active(tenant)

    def dispatched_ids(self, tenant: str) -> list[str]:
        return sorted(j for j in self.t.dispatched if self.t.jobs[j]["tenant"] == tenant
                      and self.t.jobs[j]["state"] in ACTIVE_JOB_STATES)  # fmt: skip

    def lock_ready_scenes(self, tenant: str, scene_ids: Sequence[str]) -> None:
        for scene_id in dict.fromkeys(scene_ids):
            state = self.t.scenes.get((tenant, scene_id))
            if state is None or state == "deleting":
                raise SceneGone(scene_id)
            if state != "ready":
                raise SceneNotReady(scene_id)

    def lookup_key(self, tenant: str, endpoint: str, key: str) -> tuple[str, str] | None:
        return self.t.keys.get((tenant, endpoint, key))

    def lookup_keys(self, tenant: str, endpoint: str, wanted: list[str]) -> dict[str, tuple[str, str]]:
        return {k: v for k in wanted if (v := self.t.keys.get((tenant, endpoint, k))) is not None}

    def remember_keys(self, rows: list[dict[str, str]], *, replace: bool = False) -> None:
        for r in rows:
            at = (r["tenant"], r["endpoint"], r["key"])
            if replace or at not in self.t.keys:  # ON CONFLICT DO UPDATE / DO NOTHING
                self.t.keys[at] = (r["target_id"], r["body_sha256"])

    def forget_key(self, tenant: str, endpoint: str, key: str, target_id: str) -> None:
        if self.t.keys.get((tenant, endpoint, key), ("",))[0] == target_id:
            del self.t.keys[(tenant, endpoint, key)]

    def insert_batch(self, **row: Any) -> None:
        if row["id"] in self.t.batches:
            raise DuplicateKey(f"batches.id {row['id']}")
        self.t.batches[row["id"]] = {
            **row,
            "created_at": _now(),
            "finished_at": None,
            "callback_enqueued": False,
        }

    def insert_links(self, batch_id: str, job_ids: Sequence[str]) -> None:
        self.t.links.setdefault(batch_id, []).extend(job_ids)

    def load_batch(self, tenant: str, batch_id: str) -> Mapping[str, Any] | None:
        row = self.t.batches.get(batch_id)
        if row is None or row["tenant"] != tenant:
            return None
        jobs = [self.t.jobs[j] for j in self.t.links.get(batch_id, []) if j in self.t.jobs]
        counts = {s: sum(1 for j in jobs if j["state"] == s) for s in JOB_STATES}
        active = sum(float(j["progress"]) for j in jobs if j["state"] in ACTIVE_JOB_STATES)
        return {**row, **counts, "active_progress": active}

    def batch_job_rows(self, batch_id: str, *, start: int = 0, limit: int | None = None,
                       states: Sequence[str] | None = None,
                       job_ids: Sequence[str] | None = None) -> list[tuple[int, Mapping[str, Any]]]:  # fmt: skip
        out = [(p, dict(self.t.jobs[j])) for p, j in enumerate(self.t.links.get(batch_id, []))
               if p >= start and (states is None or self.t.jobs[j]["state"] in states)
               and (job_ids is None or j in job_ids)]  # fmt: skip
        return out[:limit] if limit is not None else out

    def cancel_batch_jobs(
        self, tenant: str, batch_id: str, columns: Sequence[str]
    ) -> list[Mapping[str, Any]]:
        changed = []
        for job_id in self.t.links.get(batch_id, []):
            row = self.t.jobs[job_id]
            if row["tenant"] != tenant or row["state"] not in ACTIVE_JOB_STATES:
                continue
            row["cancel_requested"] = True
            if row["state"] == "queued":
                row.update(state="cancelled", finished_at=_now(), error="cancelled by request")
            changed.append({c: row[c] for c in columns})
        return changed

    def replace_batch_jobs(self, batch_id: str, new_of: dict[str, str]) -> None:
        self.t.links[batch_id] = [new_of.get(j, j) for j in self.t.links.get(batch_id, [])]
        self.t.batches[batch_id].update(callback_enqueued=False, finished_at=None)

    def mark_batches_finished(self, job_ids: Sequence[str]) -> list[Mapping[str, Any]]:
        out = []
        for batch_id, links in self.t.links.items():
            row = self.t.batches[batch_id]
            if row["callback_enqueued"] or not set(links) & set(job_ids):
                continue
            if any(self.t.jobs[j]["state"] in ACTIVE_JOB_STATES for j in links):
                continue
            row.update(callback_enqueued=True, finished_at=_now())
            loaded = self.load_batch(row["tenant"], batch_id)
            assert loaded is not None
            out.append(loaded)
        return out

    def enqueue_event(self, tenant: str, url: str, event: dict[str, Any]) -> bool:
        if event["event_id"] in self.t.outbox:  # ON CONFLICT (event_id) DO NOTHING
            return False
        self.t.outbox[event["event_id"]] = (tenant, url, event)
        return True

    def insert_usage_ends(self, ends: Sequence[EndRow]) -> None:
        for end in ends:
            self.t.usage.setdefault(end[0], end)  # entry_id is unique: a second end is dropped

    def replace_answers(self, job_id: str, rows: Sequence[dict[str, Any]]) -> None:
        self.t.answers[job_id] = list(rows)


class FakeJobRecords:
    """`JobRecords` in memory: `write` works on a copy and swaps it in when the block ends
    normally, so a refused unit of work (an admission, a scene gone) leaves nothing behind."""

    def __init__(self) -> None:
        self.tables = Tables()

    @contextmanager
    def write(self) -> Iterator[JobTx]:
        work = copy.deepcopy(self.tables)
        yield FakeTx(work)
        self.tables = work

    @contextmanager
    def read(self) -> Iterator[JobTx]:
        yield FakeTx(copy.deepcopy(self.tables))


@dataclass
class FakeLiveJobs:
    """`LiveJobs` in memory: a hash per job and a set of cancel flags."""

    hashes: dict[tuple[str, str], dict[bytes, bytes]] = field(default_factory=dict)
    flags: set[tuple[str, str]] = field(default_factory=set)

    def touch(self, tenant: str, job_id: str, state: str, stage: str, progress: float, *,
              terminal: bool) -> None:  # fmt: skip
        self.hashes[(tenant, job_id)] = {b"state": state.encode(), b"stage": stage.encode(),
                                         b"progress": str(progress).encode(), b"phase": b"waiting"}  # fmt: skip

    def set_progress(self, tenant: str, job_id: str, stage: str, progress: float) -> None:
        self.hashes[(tenant, job_id)] = {b"state": b"running", b"stage": stage.encode(),
                                         b"progress": str(progress).encode(), b"phase": b"active"}  # fmt: skip

    def phase(self, tenant: str, job_id: str) -> str | None:
        found = self.hashes.get((tenant, job_id), {}).get(b"phase")
        return found.decode() if found is not None else None

    def has_entry(self, tenant: str, job_id: str) -> bool:
        return (tenant, job_id) in self.hashes

    def overlays(self, pairs: Sequence[tuple[str, str]]) -> list[dict[bytes, bytes]]:
        return [dict(self.hashes.get(p, {})) for p in pairs]

    def flag_cancelled(self, pairs: Iterable[tuple[str, str]]) -> None:
        self.flags.update(pairs)

    def forget(self, pairs: Sequence[tuple[str, str]]) -> None:
        for p in pairs:
            self.hashes.pop(p, None)

    def is_cancel_flagged(self, tenant: str, job_id: str) -> bool:
        return (tenant, job_id) in self.flags
