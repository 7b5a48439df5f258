"""The signature headers of a callback POST: Standard Webhooks, and the project's former header.

Standard Webhooks (standardwebhooks.com), what a receiver's library verifies:

- ``webhook-id``: the message's id, the same on every attempt of one event (`webhook_id`: derived
  from the event's ``event_id``, never drawn per attempt), so a receiver deduplicates on it;
- ``webhook-timestamp``: Unix seconds of this attempt (the libraries refuse one more than five
  minutes from their clock);
- ``webhook-signature``: ``v1,`` + base64 HMAC-SHA256(key, id + "." + timestamp + "." + body).

The key is `config.callback_secret.signing_key` of `BFIELDS_CALLBACK_SECRET`. The former
``X-BFields-Signature: sha256=<hex>`` of HMAC-SHA256(key, timestamp + "." + body), with
``X-BFields-Timestamp``, is sent beside them for one release (deprecated: the docs' callbacks
section has the migration); ``X-BFields-Event-Id`` is the event's ``event_id``.

Why the id is a digest and not the ``event_id`` itself: event ids carry dots (the finish time's
fractions of a second), and the signed text joins id, timestamp and body with dots; an id made
of ``msg_`` and hex digits cannot shift where one part ends.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import time

from bayesian_fields_service.config.callback_secret import signing_key

ID_HEADER = "webhook-id"
STANDARD_TIMESTAMP_HEADER = "webhook-timestamp"
STANDARD_SIGNATURE_HEADER = "webhook-signature"
#: Deprecated (kept for one release beside the Standard Webhooks headers).
SIGNATURE_HEADER = "X-BFields-Signature"
TIMESTAMP_HEADER = "X-BFields-Timestamp"
EVENT_HEADER = "X-BFields-Event-Id"
#: How far from the receiver's clock a timestamp may be (the Standard Webhooks libraries' bound).
TOLERANCE_S = 300


def webhook_id(event_id: str) -> str:
    """The ``webhook-id`` of an event: ``msg_`` + 32 hex digits of SHA-256(event_id), the same on
    every attempt and from every sender (one event is one outbox row, unique by ``event_id``)."""
    return "msg_" + hashlib.sha256(event_id.encode("utf-8")).hexdigest()[:32]


def standard_signature(key: bytes, msg_id: str, timestamp: str, body: bytes) -> str:
    """``v1,<base64>`` of HMAC-SHA256(key, msg_id + "." + timestamp + "." + body)."""
    mac = hmac.new(key, f"{msg_id}.{timestamp}.".encode() + body, hashlib.sha256)
    return "v1," + base64.b64encode(mac.digest()).decode("ascii")


def legacy_signature(key: bytes, timestamp: str, body: bytes) -> str:
    """``sha256=<hex>`` of HMAC-SHA256(key, timestamp + "." + body) (the deprecated header)."""
    return "sha256=" + hmac.new(key, timestamp.encode() + b"." + body, hashlib.sha256).hexdigest()


def signed_headers(secret: str, event_id: str, body: bytes, *, now: float | None = None) -> dict[str, str]:
    """The signature headers of one attempt at Unix time `now` (default: the clock)."""
    key = signing_key(secret)
    ts = str(int(time.time() if now is None else now))
    msg_id = webhook_id(event_id)
    return {
        ID_HEADER: msg_id,
        STANDARD_TIMESTAMP_HEADER: ts,
        STANDARD_SIGNATURE_HEADER: standard_signature(key, msg_id, ts, body),
        TIMESTAMP_HEADER: ts,
        SIGNATURE_HEADER: legacy_signature(key, ts, body),
        EVENT_HEADER: event_id,
    }


def verify_legacy(
    secret: str, timestamp: str, body: bytes, header: str, *, max_age_s: float = TOLERANCE_S
) -> bool:
    """What a receiver of the deprecated header does (documented; used by the tests): signature
    and freshness. Receivers of the standard headers use a Standard Webhooks library."""
    try:
        fresh = abs(time.time() - float(timestamp)) <= max_age_s
    except ValueError:
        return False
    return fresh and hmac.compare_digest(legacy_signature(signing_key(secret), timestamp, body), header)
