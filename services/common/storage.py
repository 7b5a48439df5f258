"""Which `Store` a service process uses, and the per-tenant view of it.

Every key a tenant's request touches goes through `tenant_store`, so tenant isolation is a
property of the storage layer (keys live under ``tenants/<tenant>/``; `PrefixedStore` rejects
keys with '..' or a leading '/'), not something each endpoint must remember to check.
"""

from __future__ import annotations

import re

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.store import LocalStore, PrefixedStore, Store

from .settings import TENANT_PATTERN, ServiceSettings

TENANTS_ROOT = "tenants"


def build_store(settings: ServiceSettings) -> Store:
    """The process-wide store: `S3Store` for storage_backend='s3', else a `LocalStore` folder."""
    if settings.storage_backend == "s3":
        from .s3_store import S3Store  # boto3 is only needed by S3 deployments

        return S3Store.from_settings(settings)
    return LocalStore(settings.local_storage_root)


def tenant_store(store: Store, tenant: str) -> PrefixedStore:
    """The part of `store` that belongs to `tenant` (``tenants/<tenant>/...``)."""
    if not re.match(TENANT_PATTERN, tenant):
        raise InputError(f"invalid tenant name {tenant!r}")
    return PrefixedStore(store, f"{TENANTS_ROOT}/{tenant}")
