"""API-key authentication for the HTTP API: a FastAPI dependency that yields the caller's tenant.

Keys are resolved by `bayesian_fields_service.security.api_keys.ApiKeyRing` (inline settings or a secret file,
compared as sha256 digests in constant time). Every route takes the tenant from here and every
storage key it builds goes through `tenant_store(store, tenant)`, so one tenant can never name
another tenant's objects: a foreign id simply does not exist in its namespace (404).
"""

from __future__ import annotations

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from fastapi.security.utils import get_authorization_scheme_param

from bayesian_fields_service.security.api_keys import ApiKeyRing

API_KEY_HEADER = "X-API-Key"

#: Where the tenant fairness middleware (api/tenant_gate.py), which resolves every ``/v1/`` request's
#: key before any route runs, leaves the tenant in the request's state, so the route's dependency
#: does not resolve the same key a second time (a stat of the keys file and a digest per request).
RESOLVED_TENANT = "bfields_tenant"

_header_scheme = APIKeyHeader(name=API_KEY_HEADER, auto_error=False, description="The tenant's API key.")
_bearer_scheme = HTTPBearer(auto_error=False, description="The API key as a bearer token.")


def presented_key(
    header_key: str | None = Depends(_header_scheme),
    bearer: HTTPAuthorizationCredentials | None = Depends(_bearer_scheme),
) -> str | None:
    """The key from ``X-API-Key`` or ``Authorization: Bearer <key>``."""
    if header_key:
        return header_key
    return bearer.credentials if bearer is not None else None


def key_in_headers(x_api_key: str | None, authorization: str | None) -> str | None:
    """The key a request presents, read from its raw headers by the same rules as `presented_key`
    (FastAPI's ``APIKeyHeader`` and ``HTTPBearer``): a non-empty ``X-API-Key`` first, else the
    credentials of ``Authorization: Bearer <key>`` (scheme in any case). Why a second reading: the
    tenant fairness middleware (api/tenant_gate.py) needs the tenant before any route or dependency
    runs; tests/services/security checks that both readings agree."""
    if x_api_key:
        return x_api_key
    scheme, credentials = get_authorization_scheme_param(authorization)
    if authorization and scheme and credentials and scheme.lower() == "bearer":
        return credentials
    return None


def require_tenant(request: Request, key: str | None = Depends(presented_key)) -> str:
    """FastAPI dependency: the tenant owning the presented key, else 401."""
    tenant = request.scope.get("state", {}).get(RESOLVED_TENANT)
    if tenant is None:
        ring: ApiKeyRing = request.app.state.key_ring
        tenant = ring.tenant_for(key)
    if tenant is None:
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="missing or invalid API key (send it as X-API-Key or Authorization: Bearer)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return tenant
