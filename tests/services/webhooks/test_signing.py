"""The callback signature headers and the secret's two forms, checked against the `standardwebhooks`
package (the reference implementation's Python library) without a network: the same key, the
same signed text, the same ``v1,`` signature. The real sender is checked end to end, through a
control process and a real receiver, in `test_standard_webhooks.py`."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import re
import time
from datetime import UTC, datetime

import pytest
from pydantic import ValidationError
from standardwebhooks import Webhook, WebhookVerificationError

from bayesian_fields_service.config.callback_secret import (
    NEW_SECRET_BYTES,
    as_whsec,
    new_secret,
    signing_key,
)
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.webhooks import signing

RAW = "test-callback-secret"
BODY = json.dumps({"event_id": "job:j_1:succeeded:2026-01-01T10:00:00.123456+00:00", "state": "ok"}).encode()
EVENT_ID = "job:j_1:succeeded:2026-01-01T10:00:00.123456+00:00"


def test_raw_secret_key_is_its_utf8_bytes_and_its_whsec_form_decodes_to_them() -> None:
    assert signing_key(RAW) == RAW.encode()
    assert signing_key("clé-ü") == "clé-ü".encode()
    assert as_whsec(RAW) == "whsec_dGVzdC1jYWxsYmFjay1zZWNyZXQ="  # the value the docs show
    assert Webhook(as_whsec(RAW))._whsecret == RAW.encode()  # the library reads the same key


def test_whsec_secret_key_is_the_decoded_bytes_padded_or_not() -> None:
    key = bytes(range(32))
    padded = "whsec_" + base64.b64encode(key).decode()
    assert signing_key(padded) == key
    assert signing_key(padded.rstrip("=")) == key
    assert as_whsec(padded) == padded
    made = new_secret()
    assert made.startswith("whsec_") and len(signing_key(made)) == NEW_SECRET_BYTES
    assert made != new_secret()


@pytest.mark.parametrize(
    ("secret", "says"),
    [("whsec_not base64!", "not base64"), ("whsec_", "no key"), ("", "empty")],
)
def test_malformed_secret_is_refused_at_settings_load_without_echoing_it(secret: str, says: str) -> None:
    with pytest.raises(ValidationError) as caught:
        ServiceSettings(callback_secret=secret)  # type: ignore[arg-type]
    text = str(caught.value)
    assert "BFIELDS_CALLBACK_SECRET" in text and says in text, text
    if secret.removeprefix("whsec_"):
        assert secret not in text  # the value itself never reaches a log


@pytest.mark.parametrize("secret", [RAW, "whsec_" + base64.b64encode(b"k" * 24).decode()])
def test_headers_verify_with_the_library_and_match_its_signer(secret: str) -> None:
    now = time.time()
    headers = signing.signed_headers(secret, EVENT_ID, BODY, now=now)
    whsec = as_whsec(secret)
    assert Webhook(whsec).verify(BODY, headers) == json.loads(BODY)
    assert Webhook(signing_key(secret)).verify(BODY, headers) == json.loads(BODY)  # raw key bytes too
    expected = Webhook(whsec).sign(headers["webhook-id"], datetime.fromtimestamp(now, tz=UTC), BODY)
    assert headers["webhook-signature"] == expected
    assert headers["webhook-timestamp"] == headers["X-BFields-Timestamp"] == str(int(now))
    with pytest.raises(WebhookVerificationError):
        Webhook(new_secret()).verify(BODY, headers)


def test_deprecated_header_is_unchanged_for_a_raw_secret() -> None:
    """Receivers of the former header keep working: the same HMAC of ``timestamp.body`` with the
    secret's bytes as before this release (the formula written out here, not imported)."""
    headers = signing.signed_headers(RAW, EVENT_ID, BODY)
    ts = headers["X-BFields-Timestamp"]
    before = "sha256=" + hmac.new(RAW.encode(), ts.encode() + b"." + BODY, hashlib.sha256).hexdigest()
    assert headers["X-BFields-Signature"] == before
    assert headers["X-BFields-Event-Id"] == EVENT_ID
    assert signing.verify_legacy(RAW, ts, BODY, before)
    assert not signing.verify_legacy(RAW, ts, BODY + b" ", before)
    assert not signing.verify_legacy(
        RAW, str(int(ts) - 301), BODY, signing.legacy_signature(RAW.encode(), str(int(ts) - 301), BODY)
    )


def test_webhook_id_is_a_function_of_the_event_id_with_no_dot() -> None:
    ids = {signing.webhook_id(f"job:j_{n}:succeeded:2026-01-01T10:00:00.{n:06d}+00:00") for n in range(1000)}
    assert len(ids) == 1000
    assert signing.webhook_id(EVENT_ID) == signing.webhook_id(EVENT_ID)
    assert all(re.fullmatch(r"msg_[0-9a-f]{32}", i) for i in ids)
