"""Callbacks verified by the `standardwebhooks` package itself (issue 44, item 3), on the real stack:
the real sender (a `bfields-service control` process: its `CallbackSender`) POSTs to real HTTP
receivers (`callback_receivers`) from a real outbox (PostgreSQL), and the receiver's side is
`standardwebhooks.Webhook(secret).verify(body, headers)`, the library integrators use.

The control process runs once with a ``whsec_`` secret and once with a raw secret of the kind
earlier releases took; the receiver's library is configured with what an operator would hand
out: the ``whsec_`` string, or for the raw secret what `bfields-service callback-secret` prints
(run for real). The events are the service's own (`callbacks.job_event`, `callbacks.batch_event`),
finish times with fractions of a second included, so the event ids carry dots as real ones do."""

from __future__ import annotations

import base64
import re
import secrets
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import Engine
from standardwebhooks import Webhook, WebhookVerificationError

from bayesian_fields_service.records.database import dispose_all, engine, migrate
from bayesian_fields_service.webhooks import callbacks, signing
from tests.integration.fixtures.postgres import create_database, drop_database
from tests.integration.fixtures.processes import isolated_env, venv_bin
from tests.integration.fixtures.services import ControlServer
from tests.services.support.callback_receivers import Hit, Receiver
from tests.services.support.outbox_events import delivered, wait_for

pytestmark = [pytest.mark.integration]

WHSEC = "whsec_" + base64.b64encode(secrets.token_bytes(32)).decode()
RAW = "a-raw-secret-as-earlier-releases-took"
SENDER_ENV = {
    "BFIELDS_CALLBACK_ALLOW_PRIVATE": "true",  # the receivers are on 127.0.0.1
    "BFIELDS_CALLBACK_TIMEOUT_S": "4",
    "BFIELDS_CALLBACK_BACKOFF_S": "0.5",
    "BFIELDS_CALLBACK_POLL_S": "0.2",
}
DOCS = Path(__file__).resolve().parents[3] / "docs" / "service" / "fleets.md"


@dataclass
class Sender:
    """A control process sending callbacks signed with `secret`, and what its receivers verify with."""

    secret: str  # BFIELDS_CALLBACK_SECRET
    whsec: str  # what the receivers' library is given
    outbox: Engine
    control: ControlServer


def _cli_whsec(secret: str, tmp: Path) -> str:
    """What `bfields-service callback-secret` prints for `secret` (the operator's command)."""
    command = venv_bin("bfields-service")
    assert command is not None
    env = isolated_env(tmp, {"BFIELDS_CALLBACK_SECRET": secret})
    done = subprocess.run([command, "callback-secret"], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@pytest.fixture(scope="module", params=["whsec", "raw"])
def sender(
    request: pytest.FixtureRequest, svc_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Sender]:
    """A records database and a control process of its own per secret form."""
    secret = WHSEC if request.param == "whsec" else RAW
    tmp = tmp_path_factory.mktemp(f"stdhooks-{request.param}")
    whsec = _cli_whsec(secret, tmp)
    # the mapping the docs state: a whsec_ secret is handed out as it is, a raw one as whsec_ +
    # base64 of its UTF-8 bytes
    assert whsec == (WHSEC if secret == WHSEC else "whsec_" + base64.b64encode(RAW.encode()).decode())
    url = create_database()
    migrate(url)
    env = {**svc_env, **SENDER_ENV, "BFIELDS_CALLBACK_SECRET": secret, "BFIELDS_DATABASE_URL": url}
    control = ControlServer(env, tmp).start()
    assert control.leads
    try:
        yield Sender(secret, whsec, engine(url), control)
    finally:
        control.stop()
        dispose_all()
        drop_database(url)


@dataclass
class _Job:
    id: str
    tenant: str
    scene_id: str
    error: str | None
    batch_id: str | None
    callback_url: str | None
    finished_at: datetime | None
    state: str


@dataclass
class _Batch:
    id: str
    tenant: str
    callback_url: str | None
    total: int
    counts: dict[str, int]
    finished_at: datetime | None


def _send(outbox: Engine, event: callbacks.Event | None) -> dict[str, Any]:
    """Put one of the service's own events in the outbox, as a job's terminal write does."""
    assert event is not None
    with outbox.begin() as conn:
        assert callbacks.enqueue(conn, *event)
    return event[2]


def _job_event(
    outbox: Engine, url: str, state: str = "succeeded", error: str | None = None
) -> dict[str, Any]:
    tag = secrets.token_hex(4)
    job = _Job(f"j_{tag}", "acme", f"s_{tag}", error, None, url, datetime.now(UTC), state)
    return _send(outbox, callbacks.job_event(job))


def _delivered(sender: Sender, rx: Receiver, event: dict[str, Any], attempts: int) -> list[Hit]:
    """The receiver's hits of `event` once the outbox says it is delivered after `attempts`."""
    wait_for(
        lambda: delivered(sender.outbox, event["event_id"]) is not None, 20, f"{event['type']} delivered"
    )
    row = delivered(sender.outbox, event["event_id"])
    assert row is not None and row["attempts"] == attempts, row
    hits = [h for h in rx.snapshot() if h.event_id == event["event_id"]]
    assert len(hits) == attempts, hits
    return hits


def test_every_attempt_verifies_and_a_retry_keeps_its_webhook_id(
    sender: Sender, receivers: Callable[..., Receiver]
) -> None:
    """A receiver that fails every event's first attempt: both attempts of a job's and a batch's
    event verify with the library (given the `whsec_` string, and given the key's bytes), carry
    the same ``webhook-id`` and each their own fresh ``webhook-timestamp``; the two events' ids
    differ; the deprecated header still verifies beside them."""
    flaky = receivers("flaky")
    job = _job_event(sender.outbox, flaky.url("/job"), "failed", "the scene has no frames — give ≥ 3")
    batch = _send(sender.outbox, callbacks.batch_event(
        _Batch("b_" + secrets.token_hex(4), "acme", flaky.url("/batch"), 3, {"succeeded": 2, "failed": 1},
               datetime.now(UTC))
    ))  # fmt: skip
    assert "." in job["event_id"] and "." in batch["event_id"]  # fractions of a second, as real ones

    ids = {}
    for event in (job, batch):
        hits = _delivered(sender, flaky, event, attempts=2)
        assert [h.status for h in hits] == [500, 200]
        for hit in hits:
            assert Webhook(sender.whsec).verify(hit.body, hit.headers) == event
            assert Webhook(base64.b64decode(sender.whsec[6:])).verify(hit.body, hit.headers) == event
            assert abs(time.time() - int(hit.headers["webhook-timestamp"])) < 60
            assert signing.verify_legacy(
                sender.secret,
                hit.headers["X-BFields-Timestamp"],
                hit.body,
                hit.headers["X-BFields-Signature"],
            )
        first, second = (h.headers for h in hits)
        assert first["webhook-id"] == second["webhook-id"] == signing.webhook_id(event["event_id"])
        assert re.fullmatch(r"msg_[0-9a-f]{32}", first["webhook-id"])
        assert int(second["webhook-timestamp"]) >= int(first["webhook-timestamp"])
        assert first["webhook-signature"].startswith("v1,")
        ids[event["type"]] = first["webhook-id"]
    assert ids["job.finished"] != ids["batch.finished"]


def _other_whsec() -> str:
    """A receiver configured with another key."""
    return "whsec_" + base64.b64encode(secrets.token_bytes(32)).decode()


def _refused(whsec: str, body: bytes, headers: dict[str, str]) -> str:
    with pytest.raises(WebhookVerificationError) as caught:
        Webhook(whsec).verify(body, headers)
    return str(caught.value)


def test_tampered_callbacks_are_refused(sender: Sender, receivers: Callable[..., Receiver]) -> None:
    """One real callback, altered as an attacker or a broken proxy would: its body, its id, its
    timestamp, its signature, the signing key; the library refuses each, and takes the original."""
    ok = receivers("ok")
    event = _job_event(sender.outbox, ok.url())
    hit = _delivered(sender, ok, event, attempts=1)[0]
    body, headers = hit.body, hit.headers
    assert Webhook(sender.whsec).verify(body, headers) == event

    forged_body = body.replace(b'"succeeded"', b'"failed"')
    assert forged_body != body
    assert _refused(sender.whsec, forged_body, headers) == "No matching signature found"
    assert _refused(sender.whsec, body + b" ", headers) == "No matching signature found"
    other_id = signing.webhook_id(event["event_id"] + "x")
    assert _refused(sender.whsec, body, {**headers, "webhook-id": other_id}) == "No matching signature found"
    ts = int(headers["webhook-timestamp"])
    assert (
        _refused(sender.whsec, body, {**headers, "webhook-timestamp": str(ts - 1)})
        == "No matching signature found"
    )
    sig = headers["webhook-signature"]
    flipped = sig[:-2] + ("A" if sig[-2] != "A" else "B") + sig[-1]
    assert (
        _refused(sender.whsec, body, {**headers, "webhook-signature": flipped})
        == "No matching signature found"
    )
    assert _refused(_other_whsec(), body, headers) == "No matching signature found"
    legacy_only = {k: v for k, v in headers.items() if not k.lower().startswith("webhook-")}
    assert _refused(sender.whsec, body, legacy_only) == "Missing required headers"


def test_timestamps_outside_five_minutes_are_refused(
    sender: Sender, receivers: Callable[..., Receiver]
) -> None:
    """A real callback's id and body, signed by the service's signer (`signing.signed_headers`, what
    the sender calls) at other times: correctly signed, the library still refuses a timestamp
    more than 5 minutes old or ahead (a replayed capture), and accepts one within it; a captured
    callback whose timestamp is moved out of the window is refused for its age first."""
    ok = receivers("ok")
    event = _job_event(sender.outbox, ok.url())
    hit = _delivered(sender, ok, event, attempts=1)[0]
    now = time.time()

    def at(offset_s: float) -> dict[str, str]:
        return signing.signed_headers(sender.secret, event["event_id"], hit.body, now=now + offset_s)

    assert at(0)["webhook-id"] == hit.headers["webhook-id"]
    assert Webhook(sender.whsec).verify(hit.body, at(-240)) == event
    assert Webhook(sender.whsec).verify(hit.body, at(+240)) == event
    assert _refused(sender.whsec, hit.body, at(-310)) == "Message timestamp too old"
    assert _refused(sender.whsec, hit.body, at(+310)) == "Message timestamp too new"
    stale = {**hit.headers, "webhook-timestamp": str(int(now) - 3600)}
    assert _refused(sender.whsec, hit.body, stale) == "Message timestamp too old"


def _docs_snippets() -> dict[str, Callable[[str, dict[str, str], bytes], dict]]:
    """The receiver functions of the callbacks docs' Python blocks, run as written."""
    text = DOCS.read_text(encoding="utf-8")
    found: dict[str, Callable[[str, dict[str, str], bytes], dict]] = {}
    for block in re.findall(r"```python\n(.*?)```", text, flags=re.S):
        names = re.findall(r"^def (receive\w*)\(", block, flags=re.M)
        if names:
            scope: dict[str, Any] = {}
            exec(compile(block, str(DOCS), "exec"), scope)  # noqa: S102 - the docs' own example
            found.update({n: scope[n] for n in names})
    return found


def test_the_docs_receivers_accept_a_real_callback_and_refuse_a_forged_one(
    sender: Sender, receivers: Callable[..., Receiver]
) -> None:
    """The verifiers the callbacks docs show (the library one and the standard-library one) take
    a real callback and refuse it with a changed body."""
    snippets = _docs_snippets()
    assert set(snippets) == {"receive", "receive_stdlib"}, snippets
    ok = receivers("ok")
    event = _job_event(sender.outbox, ok.url())
    hit = _delivered(sender, ok, event, attempts=1)[0]
    for name, receive in snippets.items():
        assert receive(sender.whsec, hit.headers, hit.body) == event, name
        with pytest.raises((WebhookVerificationError, ValueError)):
            receive(sender.whsec, hit.headers, hit.body.replace(b"acme", b"acne"))
