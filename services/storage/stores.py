"""Which `Store` a service process uses, and the per-tenant view of it.

Every key a tenant's request touches goes through `tenant_store`, so tenant isolation is a
property of the storage layer (keys live under ``tenants/<tenant>/``; `PrefixedStore` rejects
keys with '..' or a leading '/'), not something each endpoint must remember to check.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Protocol

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore, PrefixedStore, Store, validate_key
from bayesian_fields_service.config.settings import TENANT_PATTERN, ServiceSettings

TENANTS_ROOT = "tenants"


def build_store(settings: ServiceSettings, *, request_path: bool = False) -> Store:
    """The process-wide store: `S3Store` for storage_backend='s3', else a `LocalStore` folder.

    `request_path` (the API): few attempts and short timeouts, so an outage is answered 503
    within about a second instead of after the workers' patient retries."""
    if settings.storage_backend == "s3":
        from bayesian_fields_service.storage.s3_store import S3Store  # boto3 is only needed by S3 deployments

        if request_path:
            t = settings.api_backend_timeout_s
            return S3Store.from_settings(
                settings, max_attempts=settings.api_backend_attempts, connect_timeout_s=t,
                read_timeout_s=max(15.0, 10 * t), retry_max_delay_s=t / 2,
            )  # fmt: skip
        return S3Store.from_settings(settings)
    return LocalStore(settings.local_storage_root)


def tenant_store(store: Store, tenant: str) -> PrefixedStore:
    """The part of `store` that belongs to `tenant` (``tenants/<tenant>/...``)."""
    if not re.match(TENANT_PATTERN, tenant):
        raise InputError(f"invalid tenant name {tenant!r}")
    return PrefixedStore(store, f"{TENANTS_ROOT}/{tenant}")


class DirectTransfers(Protocol):
    """What a bucket offers beyond `Store`: links a client uses to move bytes straight to or from
    it (presigned GETs, multipart uploads with presigned parts). `S3Store` has them; a local
    folder has none."""

    def presigned_get(self, key: str, expires_s: int = 3600, *, filename: str | None = None) -> str: ...
    def create_multipart_upload(self, key: str, *, content_type: str | None = None) -> str: ...
    def presigned_upload_part(
        self, key: str, upload_id: str, part_number: int, expires_s: int = 3600
    ) -> str: ...
    def complete_multipart_upload(
        self, key: str, upload_id: str, parts: list[dict[str, Any]] | None = None
    ) -> None: ...
    def abort_multipart_upload(self, key: str, upload_id: str) -> None: ...


def direct_transfers(store: Store) -> DirectTransfers | None:
    """The bucket's direct transfers, or None for a backend without them (a local folder)."""
    try:
        from bayesian_fields_service.storage.s3_store import S3Store
    except ImportError:  # boto3 is only installed where S3 is used
        return None
    return store if isinstance(store, S3Store) else None


@dataclass(frozen=True)
class TenantTransfers:
    """One tenant's direct transfers: keys relative to its part of the bucket (as `tenant_store`
    gives them), links valid for `expires_s`. Why a view: every key a tenant's request names goes
    through the tenant's prefix here too, so a link or an upload can never reach another tenant."""

    bucket: DirectTransfers
    view: PrefixedStore
    expires_s: int

    def _full(self, key: str) -> str:
        return self.view.prefix + validate_key(key)  # refuses '..', a leading '/', and the like

    def link(self, key: str, filename: str | None = None) -> str:
        return self.bucket.presigned_get(self._full(key), self.expires_s, filename=filename)

    def start(self, key: str) -> str:
        return self.bucket.create_multipart_upload(self._full(key))

    def part_link(self, key: str, upload_id: str, part_number: int) -> str:
        return self.bucket.presigned_upload_part(self._full(key), upload_id, part_number, self.expires_s)

    def complete(self, key: str, upload_id: str, parts: list[dict[str, Any]] | None) -> None:
        self.bucket.complete_multipart_upload(self._full(key), upload_id, parts)

    def abort(self, key: str, upload_id: str) -> None:
        self.bucket.abort_multipart_upload(self._full(key), upload_id)
