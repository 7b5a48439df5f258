"""The tenant gate's bookkeeping (services/api/tenant_gate.py) on a real event loop: slots handed to
the first waiting request, a cancelled wait leaving no trace, the queue bound, and a stream giving
its slot back up to the stream bound. The HTTP behaviour is in test_tenant_fairness.py."""

from __future__ import annotations

import asyncio

import pytest

from bayesian_fields_service.api.tenant_gate import TenantGate, TenantLoad


async def _waiting(gate: TenantGate, tenant: str, order: list[int], n: int) -> asyncio.Task[bool]:
    async def go() -> bool:
        ok = await gate.enter(tenant)
        order.append(n)
        return ok

    task = asyncio.create_task(go())
    await asyncio.sleep(0)  # let it reach the queue
    return task


def test_slots_go_to_waiting_requests_first_in_first_out_per_tenant() -> None:
    async def run() -> None:
        gate = TenantGate(limit=1, queue_max=2, streams_max=0)
        assert await gate.enter("a")
        order: list[int] = []
        first = await _waiting(gate, "a", order, 1)
        second = await _waiting(gate, "a", order, 2)
        assert not await gate.enter("a")  # the queue is full: refused, counted
        assert gate.refused == {"a": 1}
        assert await gate.enter("b")  # another tenant has slots of its own
        assert gate.load() == {"a": TenantLoad(1, 2, 0), "b": TenantLoad(1, 0, 0)}
        gate.leave("a")
        await asyncio.sleep(0)
        assert order == [1] and not second.done()
        gate.leave("a")
        await asyncio.gather(first, second)
        assert order == [1, 2]
        gate.leave("a")
        gate.leave("b")
        assert gate.load() == {}

    asyncio.run(run())


def test_a_cancelled_wait_gives_up_its_place_and_holds_nothing() -> None:
    async def run() -> None:
        gate = TenantGate(limit=1, queue_max=5, streams_max=0)
        assert await gate.enter("a")
        order: list[int] = []
        gone = await _waiting(gate, "a", order, 1)
        kept = await _waiting(gate, "a", order, 2)
        gone.cancel()
        with pytest.raises(asyncio.CancelledError):
            await gone
        assert gate.load()["a"] == TenantLoad(1, 1, 0)
        gate.leave("a")
        assert await kept and order == [2]
        gate.leave("a")
        assert gate.load() == {}

    asyncio.run(run())


def test_a_stream_gives_its_slot_back_up_to_the_stream_bound() -> None:
    async def run() -> None:
        gate = TenantGate(limit=1, queue_max=5, streams_max=1)
        assert await gate.enter("a")
        order: list[int] = []
        nxt = await _waiting(gate, "a", order, 1)
        assert gate.stream_started("a")  # the first stream moves to the tenant's streams ...
        assert await nxt  # ... and its slot goes to the waiting request
        assert gate.load()["a"] == TenantLoad(1, 0, 1)
        assert not gate.stream_started("a")  # past the stream bound a stream keeps its slot
        assert gate.load()["a"] == TenantLoad(1, 0, 1)
        gate.leave("a")
        gate.stream_ended("a")
        assert gate.load() == {}

    asyncio.run(run())
