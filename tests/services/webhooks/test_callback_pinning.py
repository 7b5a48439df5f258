"""Resolve at delivery, connect to the address that was checked (issue 30, item 4), and one
receiver's backlog delays no one else's (item 5), with the real sender against real receivers and
a real Redis. The only stand-in is the DNS resolver (a stub whose answer changes between submit
and delivery, as a rebinding attacker's name does); every receiver is a real HTTP(S) server on
127.0.0.1, reachable only because the sender connects to the stub's address: the names used here
resolve nowhere else."""

from __future__ import annotations

import datetime as dt
import socket
import ssl
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from sqlalchemy import Engine, func, insert, select

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.records.tables import callback_outbox
from bayesian_fields_service.webhooks import callbacks
from tests.integration.fixtures.postgres import records_database
from tests.services.support.callback_receivers import Receiver

pytestmark = [pytest.mark.integration]

SECRET = "test-callback-secret"
NAME = "hooks.rebind.example"  # no DNS knows it: only the stub's answer can be reached
PUBLIC = "93.184.216.34"


class ChangingResolver:
    """A resolver stub: answers `first` to its first lookup, then `later`; records every lookup."""

    def __init__(self, first: list[str], later: list[str], delay_s: float = 0.0) -> None:
        self.first, self.later, self.delay_s = first, later, delay_s
        self.asked: list[str] = []

    def __call__(self, host: str) -> list[str]:
        self.asked.append(host)
        time.sleep(self.delay_s)
        return self.first if len(self.asked) == 1 else self.later


def _settings(**over: object) -> ServiceSettings:
    base: dict[str, object] = {"callback_secret": SECRET, "callback_timeout_s": 3.0, "callback_poll_s": 0.1,
                               "callback_backoff_s": 0.2, "callback_max_attempts": 1}  # fmt: skip
    return ServiceSettings(**{**base, **over})  # type: ignore[arg-type]


@pytest.fixture
def ok() -> Iterator[Receiver]:
    r = Receiver("ok")
    yield r
    r.close()


@pytest.fixture
def outbox() -> Iterator[Engine]:
    """A records database of this test's own (the outbox is a table)."""
    with records_database() as db:
        yield db


def _open(db: Engine) -> int:
    with db.connect() as conn:
        return int(conn.execute(select(func.count()).select_from(callback_outbox).where(
            callback_outbox.c.delivered_at.is_(None), callback_outbox.c.dropped_at.is_(None))).scalar_one())  # fmt: skip


def _deliver(db: Engine, settings: ServiceSettings, url: str, resolve: ChangingResolver) -> dict:
    """Enqueue one event to `url` and let a real `CallbackSender` (using `resolve`) settle it;
    its outcome ("delivered" or the dropped row)."""
    event_id = "test:pin:" + str(time.monotonic_ns())
    with db.begin() as conn:
        assert callbacks.enqueue(conn, "t", url, {"event_id": event_id, "type": "test.pin"})
    sender = callbacks.CallbackSender(db, settings, resolve=resolve)
    sender.start()
    try:
        deadline = time.monotonic() + 10
        while _open(db) and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        sender.stop()
    assert not _open(db), "not settled"
    with db.connect() as conn:
        row = (
            conn.execute(select(callback_outbox).where(callback_outbox.c.event_id == event_id))
            .mappings()
            .one()
        )
    return dict(row) if row["dropped_at"] is not None else {"delivered": True}


def test_an_answer_changed_after_submit_cannot_aim_inward(outbox: Engine, ok: Receiver) -> None:
    """Submit: the name resolves to a public address, so the URL is accepted (with a trailing dot,
    normalised). Delivery: the same name now answers 127.0.0.1; the sender checks that answer,
    refuses it, and never connects: the receiver on 127.0.0.1 gets nothing."""
    resolve = ChangingResolver([PUBLIC], ["127.0.0.1"])
    url = f"http://{NAME}.:{ok.port}/cb"
    settings = _settings()
    assert callbacks.check_callback_url(url, settings, resolve=resolve) == url  # submit: accepted
    dropped = _deliver(outbox, settings, url, resolve)
    assert resolve.asked == [NAME, NAME]  # resolved again at delivery, the trailing dot removed both times
    assert "refused" in dropped["last_error"] and "127.0.0.1 is a loopback address" in dropped["last_error"]
    assert ok.snapshot() == []


def test_delivery_connects_to_the_checked_address_with_the_name_as_host(outbox: Engine, ok: Receiver) -> None:
    """With private addresses allowed (so 127.0.0.1 may receive), a name only the stub knows is
    delivered: the connection went to the address the check approved, with no second lookup (the
    system resolver knows no such name), the Host header is the name, and a trailing dot in the URL
    delivers like the name without it."""
    resolve = ChangingResolver(["127.0.0.1"], ["10.255.255.1"])  # a second lookup would go elsewhere
    url = f"http://{NAME.upper()}.:{ok.port}/cb?x=1"
    outcome = _deliver(outbox, _settings(callback_allow_private=True), url, resolve)
    assert outcome == {"delivered": True}, outcome
    assert resolve.asked == [NAME]
    (hit,) = ok.snapshot()
    assert hit.headers["Host"] == f"{NAME}:{ok.port}" and hit.path == "/cb?x=1"


def _self_signed(folder: Path, name: str) -> tuple[Path, Path]:
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
        .serial_number(x509.random_serial_number()).not_valid_before(now - dt.timedelta(days=1))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName(name)]), critical=False)
        .sign(key, hashes.SHA256())
    )  # fmt: skip
    cert_path, key_path = folder / "cert.pem", folder / "key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))  # fmt: skip
    return cert_path, key_path


def test_tls_uses_the_name_for_sni_and_verification(tmp_path: Path) -> None:
    """https to a name pinned to 127.0.0.1: the TLS ClientHello carries the name (SNI), and the
    certificate is verified for it (a self-signed one is refused: no callback to an unverified peer)."""
    cert, key = _self_signed(tmp_path, NAME)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(cert, key)
    seen: list[str | None] = []
    context.sni_callback = lambda _sock, server_name, _ctx: seen.append(server_name)
    listener = context.wrap_socket(socket.create_server(("127.0.0.1", 0)), server_side=True)
    port = listener.getsockname()[1]

    def serve() -> None:
        try:
            conn, _ = listener.accept()  # the handshake runs here; the client aborts it
            conn.close()
        except OSError:
            pass

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    try:
        settings = _settings(callback_allow_private=True)
        ok, why = callbacks.attempt(f"https://{NAME}:{port}/cb", "e1", b"{}", settings,
                                    deadline=time.monotonic() + 3, resolve=lambda h: ["127.0.0.1"])  # fmt: skip
    finally:
        server.join(5)
        listener.close()
    assert seen == [NAME]
    assert not ok and "CERTIFICATE_VERIFY_FAILED" in why, why


def test_slow_dns_counts_against_the_attempt_deadline() -> None:
    """A name whose DNS takes 5 s to answer: the attempt (deadline 1 s) ends in about 1 s, refused
    as not resolving, and the submit check ends by `callback_timeout_s` the same way."""
    settings = _settings(callback_allow_private=True, callback_timeout_s=1.0)
    started = time.monotonic()
    ok, why = callbacks.attempt(f"http://{NAME}/cb", "e1", b"{}", settings, deadline=started + 1.0,
                                resolve=ChangingResolver(["127.0.0.1"], [], delay_s=5))  # fmt: skip
    took = time.monotonic() - started
    assert not ok and "does not resolve" in why and took < 1.5, (why, took)
    started = time.monotonic()
    with pytest.raises(InputError, match="does not resolve"):
        callbacks.check_callback_url(f"http://{NAME}/", settings, resolve=ChangingResolver([], [], delay_s=5))
    assert time.monotonic() - started < 1.5


def test_a_backlog_for_one_receiver_delays_no_one_else(outbox: Engine, ok: Receiver) -> None:
    """300 events due for a receiver that never answers (more than the dispatcher reads at a time)
    ahead of one ordinary event: the ordinary one is still delivered at once, the silent receiver
    holding only its `callback_per_destination` share of the threads."""
    silent = Receiver("silent")
    settings = _settings(callback_allow_private=True, callback_max_attempts=3)
    assert 300 > callbacks.SCAN_WINDOW
    with outbox.begin() as conn:
        conn.execute(insert(callback_outbox), [
            {"tenant": "t", "url": silent.url(), "event_id": f"test:backlog:{n}",
             "event": {"event_id": f"test:backlog:{n}"}, "next_attempt_at": dt.datetime.now(dt.UTC) - dt.timedelta(seconds=1)}
            for n in range(300)
        ])  # fmt: skip
        callbacks.enqueue(conn, "t", ok.url("/ordinary"), {"event_id": "test:ordinary"})
    sender = callbacks.CallbackSender(outbox, settings)
    started = time.monotonic()
    sender.start()
    try:
        deadline = started + 5
        while not ok.snapshot() and time.monotonic() < deadline:
            time.sleep(0.01)
        latency = time.monotonic() - started
        # the receiver has the request a moment before the sender has read the answer: wait (at
        # most 2 s) for the ordinary attempt to end before reading what is still in flight
        ordinary = f"127.0.0.1:{ok.port}"
        settle = time.monotonic() + 2
        while ordinary in sender.in_flight() and time.monotonic() < settle:
            time.sleep(0.01)
        in_flight = sender.in_flight()
        with outbox.begin() as conn:  # the backlog is not brought back by its attempts
            conn.execute(callback_outbox.delete().where(callback_outbox.c.event_id.like("test:backlog:%")))
    finally:
        sender.stop()
        silent.close()
    print(
        f"\nordinary delivered {latency * 1000:.0f} ms after start behind 300 silent events; in flight: {in_flight}"
    )
    assert [h.event_id for h in ok.snapshot()] == ["test:ordinary"]
    assert latency < 1.0
    assert in_flight == {f"127.0.0.1:{silent.port}": settings.callback_per_destination}
    assert _open(outbox) == 0
