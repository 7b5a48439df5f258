"""The quota state of an answer in the IETF httpapi RateLimit header fields.

Why: a client that submits jobs in a loop should see its quota shrink before it is refused, and
know when to come back after. draft-ietf-httpapi-ratelimit-headers (-10) defines two Structured
Fields (RFC 9651) for that: ``RateLimit-Policy`` (the policies: a quoted name with ``q``, the
quota) and ``RateLimit`` (the current state: the name with ``r``, what remains, and ``t``, the
seconds until it comes back, where known).

The policies of this service:

- ``"jobs"``: the tenant's admission quota (`jobs.queue`): at most
  ``BFIELDS_MAX_WAITING_JOBS_PER_TENANT + BFIELDS_MAX_ACTIVE_JOBS_PER_TENANT`` unfinished jobs; one
  unit is one job (a batch of 40 takes 40). It has no time window (``w``): a unit comes back when
  one of the tenant's jobs ends. Sent on every submission that stored jobs (POST /v1/jobs,
  POST /v1/batches) and on its 429 (with ``t`` = ``Retry-After``).
- ``"concurrency"``: the tenant's requests at once on one API process (`api.tenant_gate`,
  ``qu="concurrent-requests"``), sent on the gate's 429 with ``r=0``.
- ``"requests"``: the tenant's request rate on one API process (`api.tenant_rate`, which writes
  its own fields), on every ``/v1/`` answer while the rate is on.

An answer under several policies lists each (`add_policies`): the fields are Lists.
"""

from __future__ import annotations

from collections.abc import Mapping

from starlette.datastructures import MutableHeaders

from bayesian_fields_service.jobs.queue import TenantQuota

#: The policy names (Structured Field strings, quoted in the headers).
JOBS_POLICY = "jobs"
CONCURRENCY_POLICY = "concurrency"
#: The two fields that are Lists of policies (several policies: their items joined).
LIST_FIELDS = ("RateLimit-Policy", "RateLimit")


def policy_headers(
    name: str, quota: int, remaining: int, *, reset_s: int | None = None, unit: str | None = None
) -> dict[str, str]:
    """``RateLimit-Policy`` and ``RateLimit`` for one policy (names and units are plain ASCII
    words, so quoting them needs no escapes)."""
    policy = f'"{name}";q={quota}' + (f';qu="{unit}"' if unit else "")
    state = f'"{name}";r={max(0, remaining)}' + (f";t={reset_s}" if reset_s is not None else "")
    return {"RateLimit-Policy": policy, "RateLimit": state}


def quota_headers(quota: TenantQuota, *, reset_s: int | None = None) -> dict[str, str]:
    """The headers of the tenant's job quota as a submission (or its refusal) left it."""
    return policy_headers(JOBS_POLICY, quota.limit, quota.remaining, reset_s=reset_s)


def add_policies(headers: MutableHeaders, fields: Mapping[str, str]) -> None:
    """Add `fields` to an answer's headers: a RateLimit field the answer already has (another
    policy's, e.g. the job quota of a submission) gets these items appended to its List; any
    other field (``Retry-After``) is set only where the answer has none."""
    for name, value in fields.items():
        present = headers.get(name)
        if name in LIST_FIELDS and present:
            headers[name] = f"{present}, {value}"
        else:
            headers.setdefault(name, value)
