"""The readiness probe of the API process's components: the records database, Redis and the bucket.

Why an object the state holds and not the health route probing each client: routes translate
HTTP and call a domain, never the infrastructure (issue 43), so `GET /readyz` asks this for
one status per component and only turns the answers into a response. Each status is ``ok`` or
``error: <exception type>`` (the type is enough detail for a probe; the text may name hosts).
"""

from __future__ import annotations

import redis
from sqlalchemy import Engine

from bayesian_fields_core.job.store import Store
from bayesian_fields_service.api.records_outage import OUTAGES
from bayesian_fields_service.records.database import ping

#: A key prefix nothing is stored under: listing it is the bucket's cheapest round trip.
STORAGE_PROBE = "readyz-probe/"


class Readiness:
    """Probes the process's records engine, Redis client and bucket (the request path's own, so
    the probe sees what a request would)."""

    def __init__(self, database: Engine, redis_client: redis.Redis, store: Store) -> None:
        self._database = database
        self._redis = redis_client
        self._store = store

    def check(self) -> dict[str, str]:
        """{component: status} for ``postgresql``, ``redis`` and ``storage``, in that order."""
        return {"postgresql": self._postgresql(), "redis": self._redis_status(), "storage": self._storage()}

    def _postgresql(self) -> str:
        """``SELECT 1`` on the records database: a pooled connection (pre-pinged), or a new one
        within the engine's connect timeout (`records.database.CONNECT_TIMEOUT_S`)."""
        try:
            ping(self._database)
            return "ok"
        except OUTAGES as exc:
            return f"error: {type(exc).__name__}"

    def _redis_status(self) -> str:
        try:
            self._redis.ping()
            return "ok"
        except redis.RedisError as exc:
            return f"error: {type(exc).__name__}"

    def _storage(self) -> str:
        try:
            self._store.list(STORAGE_PROBE)
            return "ok"
        except Exception as exc:  # any storage failure means not ready; the type is enough detail
            return f"error: {type(exc).__name__}"
