"""Why the domain turns a request down, as exceptions the callers map to their own answers.

Each kind says what the user should do, not which HTTP status it is: the API maps `Invalid` to
422, `Missing` to 404, `Conflict` and `Busy` to 409 and `OverQuota` to 429 with its Retry-After
(`api.edge`); the message is written for the user and names the field, the limit or the fix.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bayesian_fields_service.jobs.queue import TenantQuota


class Refused(Exception):
    """A request the domain will not carry out; `str()` is the message for the user."""


class Invalid(Refused):
    """What was asked is malformed or cannot be done (a field, a parameter, a reused key)."""


class Missing(Refused):
    """It names a job, batch or scene the tenant does not have."""


class Conflict(Refused):
    """The records' current state forbids it (a scene not ready, a job not finished)."""


class Busy(Refused):
    """Another request holds what this one needs for longer than it waits; retry later."""


class OverQuota(Refused):
    """Past the tenant's admission bound; retry after `retry_after_s`. `quota`: the bound and
    the tenant's unfinished jobs when it was refused."""

    def __init__(self, message: str, retry_after_s: int, quota: TenantQuota | None = None) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s
        self.quota = quota
