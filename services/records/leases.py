"""Leases with a deadline and a fencing token: who leads the control loops, and proof of it.

Why a lease row and not a session advisory lock: a session lock is held for as long as the
holder's connection lives, and a frozen process (SIGSTOP, a long GC or swap pause, a VM
migration) keeps its connection, so it kept the lead and nothing was dispatched for as long as it
stayed frozen. A lease is a row with a deadline in the database's own clock: the holder must renew
it before `expires_at`, and once it has passed any replica may take it, which bumps `token`. Every
statement a leader makes on the leader's behalf runs `assert_lease` first, in its own transaction,
holding the lease row ``FOR SHARE``: a take (an UPDATE of that row) waits until such a transaction
ends, and a leader that wakes after losing the lease finds its token stale and changes nothing.

The holder's local view (`Leadership.held`) ends before the row's deadline: it counts the lease
from *before* the renewing statement was sent, on the monotonic clock, so a process that was
frozen sees its lead gone the moment it wakes, without asking the database.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Connection, Engine, and_, case, func, literal, or_, select, update
from sqlalchemy.dialects.postgresql import insert

from bayesian_fields_service.records.tables import control_leases

#: The lease the control process's replicas elect their leader by.
CONTROL_LEADER = "control-leader"


class LeaseLost(Exception):
    """The fencing token is no longer the lease's current one, or the lease expired: the caller
    must not act as the leader (another replica leads, or will as soon as it asks)."""


@dataclass(frozen=True)
class Fence:
    """What a leader's statements carry: the lease's name and the token it was granted."""

    name: str
    token: int


def _deadline(ttl_s: float):  # noqa: ANN202 (an SQL expression)
    return func.now() + func.make_interval(0, 0, 0, 0, 0, 0, literal(float(ttl_s)))


def take_or_renew(database: Engine, name: str, holder: str, token: int | None, ttl_s: float) -> int | None:
    """Renew `holder`'s lease `name` (when `token` is still current and unexpired: the token
    stays), or take it (when it expired or was never held: the token is bumped). Returns the
    token now held, or None when another holder's lease is still running. One statement."""
    mine = and_(
        control_leases.c.holder == holder,
        control_leases.c.token == (token if token is not None else -1),
        control_leases.c.expires_at > func.now(),
    )
    statement = (
        insert(control_leases)
        .values(name=name, holder=holder, token=1, expires_at=_deadline(ttl_s))
        .on_conflict_do_update(
            index_elements=[control_leases.c.name],
            set_={
                "holder": holder,
                "token": control_leases.c.token + case((mine, 0), else_=1),
                "expires_at": _deadline(ttl_s),
            },
            where=or_(control_leases.c.expires_at <= func.now(), mine),
        )
        .returning(control_leases.c.token)
    )
    with database.begin() as conn:
        granted = conn.execute(statement).scalar_one_or_none()
    return int(granted) if granted is not None else None


def release(database: Engine, fence: Fence, holder: str) -> bool:
    """End `holder`'s lease now (a clean shutdown), so a standby takes it at its next try; False
    when it was no longer this holder's. The token is left as it is: the next take bumps it."""
    with database.begin() as conn:
        ended = conn.execute(
            update(control_leases)
            .where(
                control_leases.c.name == fence.name,
                control_leases.c.holder == holder,
                control_leases.c.token == fence.token,
            )
            .values(expires_at=func.now())
        )
    return bool(ended.rowcount)


def assert_lease(conn: Connection, fence: Fence) -> None:
    """Inside a leader's transaction: lock the lease row ``FOR SHARE`` and raise `LeaseLost`
    unless `fence` is its current token and it has not expired (module docstring)."""
    current = conn.execute(
        select(control_leases.c.token)
        .where(
            control_leases.c.name == fence.name,
            control_leases.c.token == fence.token,
            control_leases.c.expires_at > func.now(),
        )
        .with_for_update(read=True)
    ).first()
    if current is None:
        raise LeaseLost(f"the lease {fence.name!r} is no longer held with token {fence.token}")


def current_token(database: Engine, name: str) -> int | None:
    """The lease's token now (None: never taken), whoever holds it (tests, the health body)."""
    with database.connect() as conn:
        token = conn.execute(select(control_leases.c.token).where(control_leases.c.name == name)).scalar()
    return int(token) if token is not None else None
