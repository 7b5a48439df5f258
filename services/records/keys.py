"""The statements over `idempotency_keys` rows: (tenant, endpoint, key) -> target id and the
sha256 of the request body it was first sent with.

Why a table of their own, written in the job's transaction: a retry after a crash finds the key
exactly when it finds the jobs it names.
"""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import Connection, delete, select, text

from bayesian_fields_service.records.tables import idempotency_keys

_INSERT_KEYS = (
    "INSERT INTO idempotency_keys (tenant, endpoint, key, body_sha256, target_id) "
    "SELECT * FROM unnest(CAST(:tenant AS varchar[]), CAST(:endpoint AS varchar[]), CAST(:key AS varchar[]), "
    "CAST(:body_sha256 AS varchar[]), CAST(:target_id AS varchar[])) "
)
_KEY_COLUMNS = ("tenant", "endpoint", "key", "body_sha256", "target_id")


def lookup(conn: Connection, tenant: str, endpoint: str, key: str) -> tuple[str, str] | None:
    """(target id, body sha256) of one key, or None."""
    row = conn.execute(
        select(idempotency_keys.c.target_id, idempotency_keys.c.body_sha256).where(
            idempotency_keys.c.tenant == tenant,
            idempotency_keys.c.endpoint == endpoint,
            idempotency_keys.c.key == key,
        )
    ).first()
    return (row.target_id, row.body_sha256) if row is not None else None


def lookup_many(
    conn: Connection, tenant: str, endpoint: str, keys: Sequence[str]
) -> dict[str, tuple[str, str]]:
    """`lookup` for many keys in one query: key -> (target id, body sha256)."""
    rows = conn.execute(
        select(idempotency_keys.c.key, idempotency_keys.c.target_id, idempotency_keys.c.body_sha256).where(
            idempotency_keys.c.tenant == tenant,
            idempotency_keys.c.endpoint == endpoint,
            idempotency_keys.c.key.in_(list(keys)),
        )
    )
    return {r.key: (r.target_id, r.body_sha256) for r in rows}


def remember(conn: Connection, rows: list[dict[str, str]], *, replace: bool = False) -> None:
    """Key rows (dicts of tenant, endpoint, key, body_sha256, target_id) in one statement (arrays
    unnested: a multi-row VALUES of 5,000 rows spent longer compiling than PostgreSQL spent
    inserting); `replace` points existing keys at their new targets (a retry), otherwise a key
    already there keeps its first target."""
    if not rows:
        return
    conflict = (
        "ON CONFLICT (tenant, endpoint, key) DO UPDATE SET target_id = excluded.target_id, "
        "body_sha256 = excluded.body_sha256"
        if replace
        else "ON CONFLICT DO NOTHING"
    )
    conn.execute(text(_INSERT_KEYS + conflict), {c: [r[c] for r in rows] for c in _KEY_COLUMNS})


def forget(conn: Connection, tenant: str, endpoint: str, key: str, target_id: str) -> None:
    """Drop a key row, only while it still names `target_id`."""
    conn.execute(
        delete(idempotency_keys).where(
            idempotency_keys.c.tenant == tenant,
            idempotency_keys.c.endpoint == endpoint,
            idempotency_keys.c.key == key,
            idempotency_keys.c.target_id == target_id,
        )
    )
