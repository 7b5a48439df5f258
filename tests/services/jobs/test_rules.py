"""The jobs domain's pure rules, without a server: the write rule (`model.settle`: merge, terminal
states sticky, cancel wins), the batch status rule (`batches.batch_progress`) and fair share
(`queue.StrideClock`, `queue.choose`)."""

from __future__ import annotations

from bayesian_fields_service.jobs.batches import batch_progress, progress_of_jobs
from bayesian_fields_service.jobs.model import JobRecord, JobState, ends, merge, settle
from bayesian_fields_service.jobs.queue import StrideClock, TenantBacklog, choose
from bayesian_fields_service.jobs.usage import JobUsage
from bayesian_fields_service.records.tables import JOB_STATES, TERMINAL_JOB_STATES


def record(**kw: object) -> JobRecord:
    return JobRecord(id="j_" + "0" * 22, tenant="t", scene_id="s_" + "0" * 22, tasks=["a"], **kw)  # type: ignore[arg-type]


def test_the_states_are_the_records_states_and_terminal_is_spelled_once() -> None:
    assert tuple(JobState) == JOB_STATES
    assert {s.value for s in JobState if s.terminal} == set(TERMINAL_JOB_STATES)


def test_a_terminal_state_is_sticky_and_fields_accumulate() -> None:
    stored = record(state=JobState.failed, error="boom", stages_done=["perceive"], timings={"perceive": 1.0},
                    usage=JobUsage(cpu_seconds={"perceive": 3.0}))  # fmt: skip
    late = record(state=JobState.running, stages_done=["fuse"], timings={"fuse": 2.0},
                  usage=JobUsage(cpu_seconds={"perceive": 1.0, "fuse": 4.0}, bytes_stored=9))  # fmt: skip
    merged = merge(stored, late)
    assert merged.state == JobState.failed and merged.error == "boom"
    assert merged.stages_done == ["perceive", "fuse"]  # in STAGES order, whatever the writers' order
    assert merged.timings == {"perceive": 1.0, "fuse": 2.0}
    assert merged.usage.cpu_seconds == {"perceive": 3.0, "fuse": 4.0} and merged.usage.bytes_stored == 9
    assert merge(record(state=JobState.queued), record(state=JobState.running)).state == JobState.running


def test_a_cancel_request_is_never_lost_by_a_later_writer() -> None:
    assert merge(record(cancel_requested=True), record(state=JobState.running)).cancel_requested


def test_cancel_wins_over_a_success_written_after_it() -> None:
    accepted = record(state=JobState.running, cancel_requested=True)
    done = settle(accepted, record(state=JobState.succeeded, stages_done=["perceive", "fuse", "cluster"]))
    assert done.state == JobState.cancelled and done.error == "cancelled by request"
    # the live flag alone (a cancel accepted after the worker read its row) wins too
    flagged = settle(record(state=JobState.running), record(state=JobState.succeeded), cancel_flagged=True)
    assert flagged.state == JobState.cancelled and flagged.cancel_requested
    # without a cancel a success is a success; a failure is never rewritten
    assert (
        settle(record(state=JobState.running), record(state=JobState.succeeded)).state == JobState.succeeded
    )
    assert settle(accepted, record(state=JobState.failed, error="x")).state == JobState.failed


def test_only_the_write_that_ends_a_job_counts_as_its_end() -> None:
    running, failed = record(state=JobState.running), record(state=JobState.failed)
    assert ends(running, settle(running, failed))
    assert ends(None, failed)
    assert not ends(failed, settle(failed, record(state=JobState.succeeded)))  # a duplicate end
    assert not ends(running, settle(running, record(state=JobState.running)))


def test_batch_status_from_counts() -> None:
    now = batch_progress({"succeeded": 2, "failed": 1, "running": 1, "queued": 0}, 50.0, 4)
    assert now.counts == {"succeeded": 2, "failed": 1, "running": 1}  # states with none left out
    assert now.progress == 87.5 and not now.finished  # (3 x 100 + 50) / 4
    done = batch_progress({"succeeded": 1, "cancelled": 2}, 0.0, 3)
    assert done.progress == 100.0 and done.finished
    assert batch_progress({}, 0.0, 0).progress == 0.0  # an empty batch divides by one, not zero


def test_batch_status_from_jobs_is_the_same_rule() -> None:
    jobs = [("succeeded", 100.0), ("running", 40.0), ("queued", 0.0), ("failed", 60.0)]
    assert progress_of_jobs(jobs) == batch_progress(
        {"succeeded": 1, "running": 1, "queued": 1, "failed": 1}, 40.0, 4
    )
    assert progress_of_jobs(jobs).progress == 60.0  # an ended job counts 100 whatever its own progress


def backlog(tenant: str, interactive: int = 0, bulk: int = 0, dispatched: int = 0) -> TenantBacklog:
    return TenantBacklog(tenant, interactive, bulk, dispatched)


def test_stride_shares_dispatches_by_weight() -> None:
    clock = StrideClock()
    tenants = [backlog("a", bulk=100), backlog("b", bulk=100)]
    weights = {"a": 2.0, "b": 1.0}
    taken = {"a": 0, "b": 0}
    for _ in range(30):
        clock.observe(tenants)
        pick = choose(tenants, limit=100, skip=set())
        assert pick is not None
        clock.advance(pick, weights[pick.tenant])
        taken[pick.tenant] += 1
    assert taken == {"a": 20, "b": 10}


def test_an_idle_tenant_rejoins_at_the_current_time_without_banked_credit() -> None:
    clock = StrideClock()
    busy = backlog("a", bulk=100)
    for _ in range(10):
        clock.observe([busy])
        pick = choose([busy], limit=100, skip=set())
        assert pick is not None
        clock.advance(pick, 1.0)
    late = backlog("b", bulk=100)
    picks = []
    for _ in range(4):
        clock.observe([busy, late])
        pick = choose([busy, late], limit=100, skip=set())
        assert pick is not None
        clock.advance(pick, 1.0)
        picks.append(pick.tenant)
    assert picks.count("b") == 2  # alternates: no run of ten to catch up


def test_choose_skips_full_and_empty_tenants_and_prefers_interactive_on_a_tie() -> None:
    tenants = [
        backlog("a", bulk=3),
        backlog("b", interactive=1),
        backlog("c", bulk=5, dispatched=4),
        backlog("d"),
    ]
    pick = choose(tenants, limit=4, skip=set())
    assert pick is not None and pick.tenant == "b"
    pick = choose(tenants, limit=4, skip={"b"})
    assert pick is not None and pick.tenant == "a"  # c is at its dispatch bound, d has nothing waiting
    assert choose(tenants, limit=4, skip={"a", "b"}) is None
