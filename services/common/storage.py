"""Which `Store` a service process uses, and the per-tenant view of it.

Every key a tenant's request touches goes through `tenant_store`, so tenant isolation is a
property of the storage layer (keys live under ``tenants/<tenant>/``; `PrefixedStore` rejects
keys with '..' or a leading '/'), not something each endpoint must remember to check.
"""

from __future__ import annotations

import re

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import LocalStore, PrefixedStore, Store
from bayesian_fields_service.common.settings import TENANT_PATTERN, ServiceSettings

TENANTS_ROOT = "tenants"


def build_store(settings: ServiceSettings, *, request_path: bool = False) -> Store:
    """The process-wide store: `S3Store` for storage_backend='s3', else a `LocalStore` folder.

    `request_path` (the API): few attempts and short timeouts, so an outage is answered 503
    within about a second instead of after the workers' patient retries."""
    if settings.storage_backend == "s3":
        from bayesian_fields_service.common.s3_store import S3Store  # boto3 is only needed by S3 deployments

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
