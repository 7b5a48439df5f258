"""Accounting: what each job cost (CPU-seconds, GPU-seconds by stage, bytes stored) and the
per-tenant, per-day totals behind ``GET /v1/usage``.

Per job: `JobUsage` on the job record, filled by the worker after every stage execution (retries
and crashed runs that reached the end of their stage included: they used the machine too).
- CPU-seconds: the worker process's CPU time (`time.process_time`, all its threads: decode and
  segmentation prefetch threads included) over the stage; a pool process runs one stage at a time.
- GPU-seconds: the stage's wall time when the worker's device is CUDA (the process holds the GPU for
  the whole stage), 0 on a CPU worker.
- bytes stored: the size of everything under the job's prefix (``jobs/<id>/``: stage markers,
  intermediate arrays, result) after the stage; the scene and its shared caches are not a job's.

Per tenant and day (UTC): every stage execution and every job end is one *ledger* object in the
tenant's bucket space (``usage/<day>/<entry>.json``, the truth, written first), then added once
to a Redis hash (``bf:usage:<tenant>:<day>``; the entry's id goes into a ``...:seen`` set in the
same Lua call, so a retried write never counts twice). A read compares the day's ledger with the
seen set and replays what Redis lacks (after a Redis restart, or a worker that died between the
two writes), so the totals are exact and a read is one LIST per day plus one HGETALL.
"""

from __future__ import annotations

import json
from datetime import UTC, date, datetime, timedelta
from typing import Any

import redis
from pydantic import BaseModel, Field, computed_field

from bayesian_fields_core.job.store import ArtifactNotFound, Store, get_json, put_json

LEDGER_PREFIX = "usage/"

_APPLY = """
if redis.call('sadd', KEYS[2], ARGV[1]) == 0 then return 0 end
for i = 2, #ARGV, 2 do redis.call('hincrbyfloat', KEYS[1], ARGV[i], ARGV[i + 1]) end
return 1
"""


class JobUsage(BaseModel):
    """Resources one job used (shown in GET /v1/jobs/{id} as ``usage``)."""

    cpu_seconds: dict[str, float] = Field(
        default_factory=dict, description="CPU-seconds (process time) by stage, summed over its runs."
    )
    gpu_seconds: dict[str, float] = Field(
        default_factory=dict, description="GPU-seconds (wall time on a CUDA device) by stage; 0 on CPU."
    )
    bytes_stored: int = Field(0, ge=0, description="Bytes under the job's prefix after its last stage.")

    @computed_field(description="Sum of cpu_seconds over the stages.")  # type: ignore[prop-decorator]
    @property
    def cpu_seconds_total(self) -> float:
        return round(sum(self.cpu_seconds.values()), 3)

    @computed_field(description="Sum of gpu_seconds over the stages.")  # type: ignore[prop-decorator]
    @property
    def gpu_seconds_total(self) -> float:
        return round(sum(self.gpu_seconds.values()), 3)

    def add_stage(self, stage: str, cpu_s: float, gpu_s: float, bytes_stored: int) -> JobUsage:
        return JobUsage(
            cpu_seconds={**self.cpu_seconds, stage: round(self.cpu_seconds.get(stage, 0.0) + cpu_s, 3)},
            gpu_seconds={**self.gpu_seconds, stage: round(self.gpu_seconds.get(stage, 0.0) + gpu_s, 3)},
            bytes_stored=bytes_stored,
        )

    @staticmethod
    def merged(old: JobUsage, new: JobUsage) -> JobUsage:
        """Two writers' views of one job: usage only grows per stage, so the larger one is newer."""
        stages = set(old.cpu_seconds) | set(new.cpu_seconds) | set(old.gpu_seconds) | set(new.gpu_seconds)
        return JobUsage(
            cpu_seconds={s: max(old.cpu_seconds.get(s, 0.0), new.cpu_seconds.get(s, 0.0)) for s in stages},
            gpu_seconds={s: max(old.gpu_seconds.get(s, 0.0), new.gpu_seconds.get(s, 0.0)) for s in stages},
            bytes_stored=new.bytes_stored,
        )


def day_of(when: datetime) -> str:
    return when.astimezone(UTC).date().isoformat()


def _redis_keys(tenant: str, day: str) -> tuple[str, str]:
    return f"bf:usage:{tenant}:{day}", f"bf:usage:{tenant}:{day}:seen"


def _apply(client: redis.Redis, tenant: str, day: str, entry_id: str, fields: dict[str, float]) -> None:
    flat: list[Any] = [entry_id]
    for name, value in fields.items():
        flat += [name, repr(float(value))]
    client.eval(_APPLY, 2, *_redis_keys(tenant, day), *flat)


def stage_fields(stage: str, cpu_s: float, gpu_s: float) -> dict[str, float]:
    return {
        "stage_runs": 1,
        "cpu_seconds": cpu_s,
        "gpu_seconds": gpu_s,
        f"cpu_seconds:{stage}": cpu_s,
        f"gpu_seconds:{stage}": gpu_s,
    }


def job_fields(state: str, bytes_stored: int) -> dict[str, float]:
    return {"jobs": 1, f"jobs:{state}": 1, "bytes_stored": bytes_stored}


def record(
    store: Store, client: redis.Redis, tenant: str, entry_id: str, fields: dict[str, float], when: datetime
) -> None:
    """One ledger entry (`store` is the tenant's view): bucket first, then the Redis totals."""
    day = day_of(when)
    put_json(
        store,
        f"{LEDGER_PREFIX}{day}/{entry_id}.json",
        {"id": entry_id, "at": when.isoformat(), "fields": fields},
    )
    _apply(client, tenant, day, entry_id, fields)


def _repair_day(store: Store, client: redis.Redis, tenant: str, day: str) -> None:
    """Replay the day's ledger entries Redis has not counted (idempotent: the seen set)."""
    prefix = f"{LEDGER_PREFIX}{day}/"
    names = [k[len(prefix) : -len(".json")] for k in store.list(prefix) if k.endswith(".json")]
    seen_key = _redis_keys(tenant, day)[1]
    if not names or client.scard(seen_key) >= len(names):
        return
    seen = {m.decode() if isinstance(m, bytes) else str(m) for m in client.smembers(seen_key)}
    for name in names:
        if name in seen:
            continue
        try:
            entry = get_json(store, f"{prefix}{name}.json")
        except (ArtifactNotFound, ValueError, json.JSONDecodeError):
            continue
        _apply(client, tenant, day, name, {k: float(v) for k, v in entry.get("fields", {}).items()})


def _day_totals(raw: dict[Any, Any]) -> dict[str, Any]:
    values = {(k.decode() if isinstance(k, bytes) else str(k)): float(v) for k, v in raw.items()}
    by_stage: dict[str, dict[str, float]] = {}
    jobs_by_state: dict[str, int] = {}
    for name, value in values.items():
        kind, _, which = name.partition(":")
        if which and kind in ("cpu_seconds", "gpu_seconds"):
            by_stage.setdefault(which, {"cpu_seconds": 0.0, "gpu_seconds": 0.0})[kind] = round(value, 3)
        elif which and kind == "jobs":
            jobs_by_state[which] = int(value)
    return {
        "jobs": int(values.get("jobs", 0)),
        "jobs_by_state": jobs_by_state,
        "stage_runs": int(values.get("stage_runs", 0)),
        "cpu_seconds": round(values.get("cpu_seconds", 0.0), 3),
        "gpu_seconds": round(values.get("gpu_seconds", 0.0), 3),
        "bytes_stored": int(values.get("bytes_stored", 0)),
        "by_stage": by_stage,
    }


def days_between(start: date, end: date) -> list[str]:
    return [(start + timedelta(days=n)).isoformat() for n in range((end - start).days + 1)]


def tenant_usage(store: Store, client: redis.Redis, tenant: str, start: date, end: date) -> dict[str, Any]:
    """Totals of `tenant` per day in [start, end] (UTC, inclusive) and over the period."""
    days = []
    for day in days_between(start, end):
        _repair_day(store, client, tenant, day)
        raw = client.hgetall(_redis_keys(tenant, day)[0])
        if raw:
            days.append({"day": day, **_day_totals(raw)})
    total: dict[str, Any] = {
        "jobs": 0, "jobs_by_state": {}, "stage_runs": 0, "cpu_seconds": 0.0, "gpu_seconds": 0.0,
        "bytes_stored": 0, "by_stage": {},
    }  # fmt: skip
    for d in days:
        for name in ("jobs", "stage_runs", "bytes_stored"):
            total[name] += d[name]
        for name in ("cpu_seconds", "gpu_seconds"):
            total[name] = round(total[name] + d[name], 3)
        for state, n in d["jobs_by_state"].items():
            total["jobs_by_state"][state] = total["jobs_by_state"].get(state, 0) + n
        for stage, v in d["by_stage"].items():
            t = total["by_stage"].setdefault(stage, {"cpu_seconds": 0.0, "gpu_seconds": 0.0})
            for k in ("cpu_seconds", "gpu_seconds"):
                t[k] = round(t[k] + v[k], 3)
    return {"tenant": tenant, "from": start.isoformat(), "to": end.isoformat(), "total": total, "days": days}
