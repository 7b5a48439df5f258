"""Where a callback may go: the URL parsed and normalised once, and every address decided by property.

One function (`parse_destination`) turns a `callback_url` into a `Destination` both at submission
and before each POST, so the two can never disagree about the host (a trailing dot, upper case or
a Unicode name normalise the same way every time). Host names are validated fully (IDNA, label and
name lengths, empty labels) so a bad name is a 422 naming the problem, never an exception later.

Addresses are judged by what they *are* (`ipaddress`'s classification: only globally routable
unicast), not by a list of ranges, and IPv6 forms that carry an IPv4 address (IPv4-mapped,
IPv4-compatible, IPv4-translated, 6to4, Teredo, NAT64) are judged on the embedded address too, so
``[2002:a9fe:a9fe::]`` is the metadata address it wraps. `resolve_checked` resolves a name once
and checks every answer; the sender then connects to one of exactly those addresses
(`callback_delivery`), so a DNS answer that changes between check and connect cannot aim a
callback inward.
"""

from __future__ import annotations

import ipaddress
import re
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import urlsplit

import idna

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.config.settings import ServiceSettings

IPAddress = ipaddress.IPv4Address | ipaddress.IPv6Address
#: Resolves a host name to address strings (the default is `system_resolve`); injectable so tests
#: can make a name's answer change between submission and delivery.
Resolver = Callable[[str], list[str]]

SOURCE = "callback_url"
MAX_URL_CHARS = 2000
MAX_NAME_CHARS = 253  # RFC 1035: 255 octets on the wire, 253 characters written
MAX_LABEL_CHARS = 63
_DEFAULT_PORTS = {"http": 80, "https": 443}
_LABEL = re.compile(r"^[a-z0-9_](?:[a-z0-9_-]*[a-z0-9_])?$")
#: WHATWG URL: a host whose last label is a number is an IPv4 address (in some legacy form).
_NUMERIC_LABEL = re.compile(r"^(?:[0-9]+|0x[0-9a-f]*)$", re.IGNORECASE)
#: The full stops UTS 46 maps to "." (ideographic, fullwidth, halfwidth ideographic).
_UNICODE_DOTS = str.maketrans({"\u3002": ".", "\uff0e": ".", "\uff61": "."})

_TRANSLATED_PREFIX = 0xFFFF0000  # ::ffff:0:0:0/96, top 96 bits
_NAT64_PREFIX = 0x0064FF9B << 64  # 64:ff9b::/96, top 96 bits
_NAT64_WELL_KNOWN = ipaddress.IPv6Network("64:ff9b::/96")
_NAT64_LOCAL = ipaddress.IPv6Network("64:ff9b:1::/48")

#: Names for the messages only; the decision is `_class_refusal`'s, by property.
_NAMED_RANGES: tuple[tuple[ipaddress.IPv4Network | ipaddress.IPv6Network, str], ...] = tuple(
    (ipaddress.ip_network(net), name)
    for net, name in (
        ("100.64.0.0/10", "shared address space (RFC 6598)"),
        ("198.18.0.0/15", "benchmarking (RFC 2544)"),
        ("192.0.2.0/24", "documentation (RFC 5737)"),
        ("198.51.100.0/24", "documentation (RFC 5737)"),
        ("203.0.113.0/24", "documentation (RFC 5737)"),
        ("2001:db8::/32", "documentation (RFC 3849)"),
        ("192.0.0.0/24", "IETF protocol assignments (RFC 6890)"),
        ("255.255.255.255/32", "broadcast"),
    )
)


@dataclass(frozen=True)
class Destination:
    """A callback URL as the sender uses it: the normalised host and everything the POST needs."""

    scheme: str  # "http" or "https"
    host: str  # lower-case ASCII (IDNA A-labels), no trailing dot; an IPv6 address without brackets
    port: int
    target: str  # path and query, at least "/"
    address: IPAddress | None  # the host when it is an IP address

    @property
    def key(self) -> str:
        """host:port, what the per-destination bound counts."""
        return f"{self._host_text}:{self.port}"

    @property
    def authority(self) -> str:
        """The Host header: the host, and the port when it is not the scheme's default."""
        default = _DEFAULT_PORTS[self.scheme] == self.port
        return self._host_text if default else f"{self._host_text}:{self.port}"

    @property
    def url(self) -> str:
        return f"{self.scheme}://{self.authority}{self.target}"

    @property
    def _host_text(self) -> str:
        return f"[{self.host}]" if isinstance(self.address, ipaddress.IPv6Address) else self.host


def _refuse(message: str) -> InputError:
    return InputError(message, source=SOURCE)


# ---- parsing ---------------------------------------------------------------------------------
def parse_destination(url: str) -> Destination:
    """The URL's destination, or `InputError` naming what is wrong with it (422 at the API)."""
    if len(url) > MAX_URL_CHARS:
        raise _refuse(f"longer than {MAX_URL_CHARS} characters")
    if any(c <= " " or c == "\x7f" for c in url):
        raise _refuse("the URL contains a space or a control character")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:  # a bad port or an unbalanced [ ]
        raise _refuse(f"not a valid URL ({exc})") from None
    scheme = parts.scheme.lower()
    if scheme not in _DEFAULT_PORTS:
        raise _refuse(f"scheme {parts.scheme!r} is not allowed (http or https)")
    if "@" in parts.netloc:
        raise _refuse("credentials in the URL are not allowed")
    if "\\" in parts.netloc:
        raise _refuse("a backslash in the host is not allowed")
    if port == 0:
        raise _refuse("port 0 is not allowed")
    raw_host = parts.hostname or ""
    if not raw_host:
        raise _refuse("the URL names no host")
    address: IPAddress | None
    if parts.netloc.startswith("["):
        host, address = _ipv6_literal(raw_host)
    else:
        host, address = _host_or_ipv4(raw_host)
    target = parts.path or "/"
    if parts.query:
        target += "?" + parts.query
    return Destination(scheme, host, port or _DEFAULT_PORTS[scheme], target, address)


def _ipv6_literal(raw: str) -> tuple[str, IPAddress]:
    if "%" in raw:
        raise _refuse(f"an IPv6 zone id ({raw!r}) is not allowed")
    try:
        address = ipaddress.IPv6Address(raw)
    except ValueError:
        raise _refuse(f"[{raw}] is not a valid IPv6 address") from None
    return str(address), address


def _host_or_ipv4(raw: str) -> tuple[str, IPAddress | None]:
    """A name or an IPv4 address, told apart as a browser does (WHATWG URL): by the last label
    being a number, after the Unicode full stops became dots and after IDNA mapping (so
    ``127。0。0。1`` is 127.0.0.1 and ``x.１２７`` is a malformed address, not a name)."""
    raw = raw.translate(_UNICODE_DOTS)
    dotted = raw.endswith(".")
    name = raw[:-1] if dotted else raw
    if not name:
        raise _refuse("the URL names no host")
    if not _NUMERIC_LABEL.match(name.rsplit(".", 1)[-1]):
        name = normalise_name(name)
        if not _NUMERIC_LABEL.match(name.rsplit(".", 1)[-1]):
            return name, None
    return _ipv4(name, raw, dotted)


def _ipv4(name: str, raw: str, dotted: bool) -> tuple[str, IPAddress]:
    """`name` as an IPv4 address in canonical dotted-quad form, or a refusal naming `raw`."""
    try:
        address = ipaddress.IPv4Address(name)
    except ValueError:
        raise _refuse(
            f"host {raw!r} is not a canonical IPv4 address (decimal, octal, hex and short forms are refused)"
        ) from None
    if dotted:
        raise _refuse(f"host {raw!r}: an IP address is written without a trailing dot")
    return str(address), address


def normalise_name(name: str) -> str:
    """A host name as lower-case ASCII (IDNA 2008 with UTS 46 mapping), or `InputError` naming
    the label at fault: an empty label, one over 63 characters, a character no host name has, or
    an ``xn--`` label that is not valid IDNA. The caller has removed one trailing dot."""
    labels = name.split(".")
    out: list[str] = []
    for label in labels:
        if not label:
            raise _refuse(f"host {name!r} has an empty label (two dots in a row or a leading dot)")
        out.append(_ascii_label(label))
    host = ".".join(out)
    if len(host) > MAX_NAME_CHARS:
        raise _refuse(f"host name is {len(host)} characters; at most {MAX_NAME_CHARS}")
    return host


def _ascii_label(label: str) -> str:
    shown = label if len(label) <= 40 else label[:37] + "..."
    if label.isascii():
        ascii_label = label.lower()
        if len(ascii_label) > MAX_LABEL_CHARS:
            raise _refuse(f"host label {shown!r} is {len(label)} characters; at most {MAX_LABEL_CHARS}")
        if ascii_label.startswith("xn--"):
            try:
                idna.decode(ascii_label)
            except (idna.IDNAError, UnicodeError, ValueError) as exc:
                raise _refuse(f"host label {shown!r} is not valid IDNA ({exc})") from None
        elif not _LABEL.match(ascii_label):
            raise _refuse(
                f"host label {shown!r} may hold only letters, digits, '-' and '_', and neither "
                "starts nor ends with '-'"
            )
        return ascii_label
    try:
        encoded = idna.encode(label, uts46=True).decode("ascii")
    except (idna.IDNAError, UnicodeError, ValueError) as exc:
        raise _refuse(f"host label {shown!r} cannot be encoded as IDNA ({exc})") from None
    if len(encoded) > MAX_LABEL_CHARS:
        raise _refuse(f"host label {shown!r} is {len(encoded)} characters in IDNA; at most {MAX_LABEL_CHARS}")
    return encoded


# ---- the address policy ----------------------------------------------------------------------
def embedded_ipv4(address: IPAddress) -> list[ipaddress.IPv4Address]:
    """IPv4 addresses an IPv6 address carries (and a packet to it may reach): IPv4-mapped
    (``::ffff:0:0/96``), IPv4-translated (``::ffff:0:0:0/96``), IPv4-compatible (``::/96``),
    6to4 (``2002::/16``), Teredo (``2001::/32``: server and client) and NAT64 (``64:ff9b::/96``
    and the local-use ``64:ff9b:1::/48``)."""
    if not isinstance(address, ipaddress.IPv6Address):
        return []
    found: list[ipaddress.IPv4Address] = []
    if address.ipv4_mapped is not None:
        found.append(address.ipv4_mapped)
    if address.sixtofour is not None:
        found.append(address.sixtofour)
    if address.teredo is not None:
        found.extend(address.teredo)
    value = int(address)
    low = ipaddress.IPv4Address(value & 0xFFFFFFFF)
    prefix = value >> 32
    compatible = prefix == 0 and value > 1  # not :: and ::1, which are themselves
    if compatible or prefix in (_TRANSLATED_PREFIX, _NAT64_PREFIX) or address in _NAT64_LOCAL:
        found.append(low)
    return found


def _class_refusal(address: IPAddress, *, allow_private: bool) -> str | None:
    """Why `address` is no destination, judged on the address alone, or None when it is one."""
    if address.is_unspecified:
        return "the unspecified address"
    if address.is_multicast:
        return "a multicast address"
    if address == ipaddress.IPv4Address("255.255.255.255"):
        return "the broadcast address"
    if allow_private:
        return None
    if address.is_loopback:
        return "a loopback address"
    if address.is_link_local:
        return "a link-local address"
    site_local = isinstance(address, ipaddress.IPv6Address) and address.is_site_local
    if address.is_global and not (address.is_reserved or address.is_private or site_local):
        return None
    for network, name in _NAMED_RANGES:
        if address.version == network.version and address in network:
            return name
    if address.is_reserved:
        return "a reserved address"
    if address.is_private:
        return "a private address"
    return "not a globally routable address"


def address_refusal(address: IPAddress, *, allow_private: bool) -> str | None:
    """Why `address` may not receive a callback, or None. Decided on the address and on every IPv4
    address embedded in it: an embedded address judged first (the one a packet would reach)."""
    for inner in embedded_ipv4(address):
        why = _class_refusal(inner, allow_private=allow_private)
        if why is not None:
            return f"{address} embeds {inner}, {why}"
    if address in _NAT64_WELL_KNOWN:  # a translator's prefix (what DNS64 answers on IPv6-only
        return None  # networks): the packet goes where its IPv4 part says, judged above
    why = _class_refusal(address, allow_private=allow_private)
    return None if why is None else f"{address} is {why}"


# ---- resolving and the whole check -----------------------------------------------------------
def system_resolve(host: str) -> list[str]:
    """The host's addresses from the system resolver (TCP), in its preference order."""
    seen: dict[str, None] = {}
    for info in socket.getaddrinfo(host, None, type=socket.SOCK_STREAM):
        seen.setdefault(str(info[4][0]), None)
    return list(seen)


def resolve_within(resolve: Resolver, host: str, timeout_s: float) -> list[str]:
    """`resolve(host)`, or `TimeoutError` once `timeout_s` has passed.

    `getaddrinfo` takes no timeout, and the name's own DNS servers (the tenant's) decide how long
    it blocks, so it runs in a daemon thread that the caller stops waiting for: an attempt's
    deadline covers resolving too. An abandoned lookup ends on the system resolver's own timeout;
    at most `callback_per_destination` of them per name are started at once."""
    if timeout_s <= 0:
        raise TimeoutError("no time left to resolve")
    result: list[list[str]] = []
    failure: list[BaseException] = []

    def run() -> None:
        try:
            result.append(resolve(host))
        except BaseException as exc:  # handed to the waiting caller
            failure.append(exc)

    worker = threading.Thread(target=run, name="bfields-callback-resolve", daemon=True)
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        raise TimeoutError(f"no answer within {timeout_s:.1f} s")
    if failure:
        raise failure[0]
    return result[0]


def resolve_checked(
    dest: Destination,
    settings: ServiceSettings,
    resolve: Resolver | None = None,
    *,
    timeout_s: float | None = None,
) -> list[IPAddress]:
    """Every address `dest` resolves to, each allowed by the policy, or `InputError` naming the
    first refused one (a name with any non-public answer is refused as a whole: which answer a
    connection would use is the resolver's choice, not ours). Resolving ends by `timeout_s`
    (default `callback_timeout_s`): a name whose DNS does not answer in time does not resolve."""
    if dest.address is not None:
        answers: list[IPAddress] = [dest.address]
    else:
        limit = settings.callback_timeout_s if timeout_s is None else timeout_s
        try:
            raw = resolve_within(resolve or system_resolve, dest.host, limit)
        except TimeoutError as exc:
            raise _refuse(f"host {dest.host!r} does not resolve ({exc})") from None
        except (OSError, UnicodeError):
            raise _refuse(f"host {dest.host!r} does not resolve") from None
        try:
            answers = [ipaddress.ip_address(a.split("%", 1)[0]) for a in raw]
        except ValueError:
            raise _refuse(f"host {dest.host!r} resolved to something that is not an address") from None
        if not answers:
            raise _refuse(f"host {dest.host!r} does not resolve")
    for address in answers:
        why = address_refusal(address, allow_private=settings.callback_allow_private)
        if why is not None:
            hint = (
                ""
                if settings.callback_allow_private
                else "; allowed only with BFIELDS_CALLBACK_ALLOW_PRIVATE"
            )
            named = "" if dest.address is not None else f"host {dest.host!r}: "
            raise _refuse(f"{named}{why}: callbacks go to public addresses only{hint}")
    return answers


def host_allowed(host: str, patterns: list[str]) -> bool:
    """Whether the normalised `host` matches `BFIELDS_CALLBACK_ALLOWED_HOSTS` (``*.x`` = x and below)."""
    for pattern in patterns:
        p = pattern.strip().lower().rstrip(".")
        if p.startswith("*."):
            suffix = p[2:]
            if host == suffix or host.endswith("." + suffix):
                return True
        elif host == p:
            return True
    return False


def check_destination(
    url: str,
    settings: ServiceSettings,
    resolve: Resolver | None = None,
    *,
    timeout_s: float | None = None,
) -> tuple[Destination, list[IPAddress]]:
    """The destination and its checked addresses, or `InputError` naming the rule: the one check
    run at submission and again before every POST (there with the time left of the attempt as
    `timeout_s`, so resolving counts against its deadline)."""
    if settings.callback_secret is None:
        raise _refuse("callbacks are not enabled on this service (no BFIELDS_CALLBACK_SECRET)")
    dest = parse_destination(url)
    if settings.callback_allowed_hosts and not host_allowed(dest.host, settings.callback_allowed_hosts):
        raise _refuse(f"host {dest.host!r} is not in BFIELDS_CALLBACK_ALLOWED_HOSTS")
    return dest, resolve_checked(dest, settings, resolve, timeout_s=timeout_s)
