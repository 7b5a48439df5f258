"""Callback destinations decided by property (issue 30, item 4): every non-public address the
attacks used, in every spelling (embedded IPv4 included), and every malformed host name is a 422
naming the problem, on POST /v1/jobs and on POST /v1/batches (a real API, never a 500); the rules
themselves (`check_callback_url`) with an injected resolver, so no test depends on public DNS."""

from __future__ import annotations

import ipaddress
from collections.abc import Iterator

import httpx
import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.webhooks.callback_destinations import (
    address_refusal,
    embedded_ipv4,
    parse_destination,
)
from bayesian_fields_service.webhooks.callbacks import check_callback_url
from tests.integration.fixtures.services import ApiServer

SECRET = "test-callback-secret"
LONG_LABEL = "a" * 300
LABEL_64 = "b" * 64

#: (URL, a fragment of the 422's message): the message must name the right reason, so a URL
#: refused for some other reason (say, "does not resolve") fails the test.
NON_PUBLIC: list[tuple[str, str]] = [
    # what the attacks got accepted
    ("http://100.64.0.1/", "shared address space"),
    ("http://100.100.100.200/latest/meta-data/", "shared address space"),
    ("http://[2002:a9fe:a9fe::]/", "embeds 169.254.169.254"),  # 6to4
    # Teredo: client 127.0.0.1 (stored inverted), client 169.254.169.254, server 127.0.0.1
    ("http://[2001:0:4136:e378:8000:63bf:80ff:fffe]/", "embeds 127.0.0.1"),
    ("http://[2001:0:4136:e378::5601:5601]/", "embeds 169.254.169.254"),
    ("http://[2001:0:7f00:1::f7f7:f7f7]/", "embeds 127.0.0.1"),
    # NAT64 well-known prefix
    ("http://[64:ff9b::7f00:1]/", "embeds 127.0.0.1"),
    ("http://[64:ff9b::a9fe:a9fe]/", "embeds 169.254.169.254"),
    ("http://[64:ff9b::127.0.0.1]/", "embeds 127.0.0.1"),
    ("http://198.18.0.1/", "benchmarking"),
    ("http://192.0.2.1/", "documentation"),
    ("http://240.0.0.1/", "reserved"),
    ("http://224.0.0.1/", "multicast"),
    (f"http://{LONG_LABEL}.example.com/", "is 300 characters; at most 63"),
    (f"http://{LABEL_64}.example.com/", "is 64 characters; at most 63"),
    ("http://" + ".".join(["c" * 60] * 5) + "/", "at most 253"),
    ("http://127.0.0.1.:8080/", "without a trailing dot"),
    ("http://127\u30020\u30020\u30021/", "127.0.0.1 is a loopback address"),  # ideographic full stops
    ("http://10\uff0e0\uff0e0\uff0e1\uff0e/", "without a trailing dot"),  # fullwidth, trailing
    ("http://a.\uff11\uff12\uff17/", "not a canonical IPv4"),  # a fullwidth number is a number
    ("http://xn--.example.com/", "not valid IDNA"),
    ("http://xn--zz-.example.com/", "not valid IDNA"),
    ("http://xn--a.example.com/", "not valid IDNA"),
    ("http://a\u2603\ufe0f.example.com/", "cannot be encoded as IDNA"),
    ("http://ex..example.com/", "empty label"),
    ("http://-x.example.com/", "neither starts nor ends with '-'"),
    # what held before and must keep holding
    ("http://2130706433/", "not a canonical IPv4"),
    ("http://017700000001/", "not a canonical IPv4"),
    ("http://0177.0.0.1/", "not a canonical IPv4"),
    ("http://0x7f.0.0.1/", "not a canonical IPv4"),
    ("http://127.1/", "not a canonical IPv4"),
    ("http://[::ffff:127.0.0.1]/", "embeds 127.0.0.1"),
    ("http://[::1]/", "loopback"),
    ("http://0.0.0.0/", "unspecified"),
    ("http://localhost./", "loopback"),  # the system resolver's answer, checked
    ("http://user:pw@127.0.0.1/", "credentials"),
    ("http://@127.0.0.1/", "credentials"),
    ("http://8.8.8.8@127.0.0.1/", "credentials"),
    ("http://169.254.169.254/latest/meta-data/", "link-local"),
    ("http://[fe80::1]/", "link-local"),
    ("http://10.0.0.1/", "private"),
    ("http://172.16.0.1/", "private"),
    ("http://192.168.1.1/", "private"),
    ("http://[fc00::1]/", "private"),
    ("ftp://127.0.0.1/x", "scheme 'ftp'"),
    ("file:///etc/passwd", "scheme 'file'"),
    ("gopher://8.8.8.8/", "scheme 'gopher'"),
]


def _settings(**over: object) -> ServiceSettings:
    return ServiceSettings(callback_secret=SECRET, **over)  # type: ignore[arg-type]


def _public(_host: str) -> list[str]:
    return ["93.184.216.34"]


# ---- the rules in-process --------------------------------------------------------------------
@pytest.mark.parametrize(("url", "why"), NON_PUBLIC, ids=[u[:48] for u, _ in NON_PUBLIC])
def test_rules_refuse_non_public(url: str, why: str) -> None:
    resolve = None if "localhost" in url else _public  # every name "resolves" to a public address
    with pytest.raises(InputError, match="callback_url") as refused:
        check_callback_url(url, _settings(), resolve=resolve)
    assert why in str(refused.value)


@pytest.mark.parametrize(
    "url",
    ["http://callbacks.example.com/hook", "https://8.8.8.8/x?y=1", "http://[2606:4700::1]:8080/",
     "http://[2002:808:808::1]/", "http://[64:ff9b::8.8.8.8]/", "http://b\u00fccher.example/", "http://e_x.example.com/"],
)  # fmt: skip
def test_rules_allow_public(url: str) -> None:
    assert check_callback_url(url, _settings(), resolve=_public) == url


def test_a_name_with_any_non_public_answer_is_refused() -> None:
    with pytest.raises(InputError, match="10.1.2.3 is a private address"):
        check_callback_url(
            "http://mixed.example/", _settings(), resolve=lambda h: ["93.184.216.34", "10.1.2.3"]
        )
    with pytest.raises(InputError, match="does not resolve"):
        check_callback_url("http://none.example/", _settings(), resolve=lambda h: [])


def test_allow_private_still_refuses_what_is_never_a_receiver() -> None:
    private = _settings(callback_allow_private=True)
    assert check_callback_url("http://127.0.0.1:9/", private)
    assert check_callback_url("http://100.64.0.1/", private)
    for url in ("http://0.0.0.0/", "http://[::]/", "http://224.0.0.1/", "http://255.255.255.255/",
                "http://127.0.0.1.:9/", "http://2130706433/", f"http://{LABEL_64}.x/"):  # fmt: skip
        with pytest.raises(InputError):
            check_callback_url(url, private)


def test_allowed_hosts_match_the_normalised_name() -> None:
    listed = _settings(callback_allowed_hosts=["Hooks.Example.com.", "*.partner.example"])
    for url in ("http://hooks.example.com./a", "http://HOOKS.example.com/a", "http://x.partner.example/",
                "http://partner.example/"):  # fmt: skip
        assert check_callback_url(url, listed, resolve=_public) == url
    for url in ("http://evilhooks.example.com/", "http://xpartner.example/", "http://8.8.8.8/"):
        with pytest.raises(InputError, match="BFIELDS_CALLBACK_ALLOWED_HOSTS"):
            check_callback_url(url, listed, resolve=_public)


def test_trailing_dot_and_case_normalise_to_one_destination() -> None:
    a = parse_destination("http://Example.COM./hook?x=1")
    b = parse_destination("http://example.com:80/hook?x=1")
    assert a == b and a.host == "example.com" and a.authority == "example.com" and a.key == "example.com:80"
    assert parse_destination("http://Example\u3002COM\uff0e/hook?x=1") == b  # Unicode full stops
    v6 = parse_destination("https://[2606:4700:0::1]:8443/")
    assert v6.host == "2606:4700::1" and v6.authority == "[2606:4700::1]:8443" and v6.target == "/"


def test_embedded_ipv4_is_unwrapped() -> None:
    cases = {
        "::ffff:169.254.169.254": "169.254.169.254",  # IPv4-mapped
        "::ffff:0:a9fe:a9fe": "169.254.169.254",  # IPv4-translated
        "::a9fe:a9fe": "169.254.169.254",  # IPv4-compatible
        "2002:a9fe:a9fe::1": "169.254.169.254",  # 6to4
        "64:ff9b::a9fe:a9fe": "169.254.169.254",  # NAT64
        "64:ff9b:1::a9fe:a9fe": "169.254.169.254",  # NAT64, local use
    }
    for outer, inner in cases.items():
        assert ipaddress.IPv4Address(inner) in embedded_ipv4(ipaddress.ip_address(outer)), outer
        assert address_refusal(ipaddress.ip_address(outer), allow_private=False) is not None
    server, client = embedded_ipv4(ipaddress.ip_address("2001:0:4136:e378:8000:63bf:80ff:fffe"))  # Teredo
    assert (str(server), str(client)) == ("65.54.227.120", "127.0.0.1")
    assert (
        embedded_ipv4(ipaddress.ip_address("::1")) == []
        and embedded_ipv4(ipaddress.ip_address("8.8.8.8")) == []
    )


# ---- at the API: jobs and batches ------------------------------------------------------------
@pytest.fixture(scope="module")
def callback_api(
    tmp_path_factory: pytest.TempPathFactory, svc_env: dict[str, str], test_api_keys: dict[str, str]
) -> Iterator[ApiServer]:
    """The test API with callbacks on and the default policy (no private addresses)."""
    env = {**svc_env, "BFIELDS_CALLBACK_SECRET": SECRET, "BFIELDS_CALLBACK_ALLOW_PRIVATE": "false"}
    server = ApiServer(
        env=env, log_dir=tmp_path_factory.mktemp("callback-api"), keys=dict(test_api_keys)
    ).start()
    yield server
    server.stop()


@pytest.mark.integration
def test_every_non_public_destination_is_refused_at_submit(
    callback_api: ApiServer, stored_scene: dict
) -> None:
    """One real API, every URL of the list on both routes: 422 with the reason, never a 500."""
    failures = []
    with callback_api.client("tenant-a") as client:
        for url, why in NON_PUBLIC:
            for route, body in (
                ("/v1/jobs", {"scene_id": stored_scene["id"], "tasks": ["a"], "callback_url": url}),
                (
                    "/v1/batches",
                    {"scene_ids": [stored_scene["id"]], "task_lists": [["a"]], "callback_url": url},
                ),
            ):
                resp = client.post(route, json=body)
                detail = resp.json().get("detail") if resp.status_code == 422 else None
                if not (isinstance(detail, str) and "callback_url" in detail and why in detail):
                    failures.append(f"{route} {url[:60]}: {resp.status_code} {resp.text[:200]}")
        # and the service still takes an allowed URL shape (refused only for being unresolvable here,
        # by name): the route works, the refusals above are the rules'
        assert client.get("/healthz").status_code == 200
    assert failures == []


@pytest.mark.integration
def test_submit_accepts_a_public_literal(callback_api: ApiServer, stored_scene: dict) -> None:
    """The control: the same route takes a public address (so the refusals are the rules', not the route's)."""
    with callback_api.client("tenant-a") as client:
        resp = client.post("/v1/batches", json={
            "scene_ids": [stored_scene["id"]], "task_lists": [["a"]], "callback_url": "http://8.8.8.8/hook",
        })  # fmt: skip
        assert resp.status_code == 202, resp.text
        batch = resp.json()
        cancel = client.post(f"/v1/batches/{batch['id']}/cancel")
        assert cancel.status_code in (200, 202), cancel.text


def test_no_module_level_api_needed() -> None:
    """Guard: httpx is what the API tests speak (keeps the import used when run alone)."""
    assert httpx.codes.UNPROCESSABLE_ENTITY == 422
