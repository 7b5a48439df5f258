"""API key -> tenant lookup from the settings' inline keys and the secret keys file.

Keys may be stored in clear or as ``sha256:<hex>`` of the key, so an operator can keep only hashes
in a ConfigMap or a file. A presented key is compared against every entry with
`hmac.compare_digest` so the lookup time does not reveal how much of a key matched. The file is
re-read when its modification time changes, which lets keys rotate without restarting the API.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import re
import threading
from pathlib import Path

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.config.settings import TENANT_PATTERN, ServiceSettings

_HASH_PREFIX = "sha256:"


def hash_api_key(key: str) -> str:
    """The stored form of a key: ``sha256:<hex digest>``."""
    return _HASH_PREFIX + hashlib.sha256(key.encode()).hexdigest()


def parse_keys_file(path: Path) -> dict[str, str]:
    """Read a keys file: a JSON object ``{key: tenant}`` or lines ``<key> <tenant>``."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"cannot read API keys file: {exc}", source=str(path)) from None
    entries: dict[str, str] = {}
    if text.lstrip().startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"invalid JSON: {exc}", source=str(path)) from None
        if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
            raise InputError("expected a JSON object mapping key -> tenant", source=str(path))
        entries = dict(data)
    else:
        for lineno, raw in enumerate(text.splitlines(), 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            fields = line.split()
            if len(fields) != 2:
                raise InputError(f"line {lineno}: expected '<key> <tenant>'", source=str(path))
            entries[fields[0]] = fields[1]
    for tenant in entries.values():
        if not re.match(TENANT_PATTERN, tenant):
            raise InputError(f"invalid tenant name {tenant!r}", source=str(path))
    return entries


def _digest(stored: str) -> bytes:
    """The sha256 digest an entry stands for (hashing clear-text entries on the fly)."""
    if stored.startswith(_HASH_PREFIX):
        try:
            return bytes.fromhex(stored[len(_HASH_PREFIX) :])
        except ValueError:
            raise InputError(f"malformed hashed API key {stored[:16]}...") from None
    return hashlib.sha256(stored.encode()).digest()


class ApiKeyRing:
    """Resolves presented API keys to tenant names."""

    def __init__(self, inline: dict[str, str], keys_file: Path | None = None) -> None:
        self._inline = [(_digest(k), t) for k, t in inline.items()]
        self._file = keys_file
        self._file_entries: list[tuple[bytes, str]] = []
        self._file_mtime: float | None = None
        self._lock = threading.Lock()

    @classmethod
    def from_settings(cls, settings: ServiceSettings) -> ApiKeyRing:
        return cls(settings.api_keys, settings.api_keys_file)

    def _entries(self) -> list[tuple[bytes, str]]:
        if self._file is None:
            return self._inline
        with self._lock:
            mtime = self._file.stat().st_mtime if self._file.exists() else None
            if mtime != self._file_mtime:
                parsed = parse_keys_file(self._file) if mtime is not None else {}
                self._file_entries = [(_digest(k), t) for k, t in parsed.items()]
                self._file_mtime = mtime
            return self._inline + self._file_entries

    def tenant_for(self, presented: str | None) -> str | None:
        """The tenant owning `presented`, or None. Every entry is compared (constant time)."""
        if not presented:
            return None
        digest = hashlib.sha256(presented.encode()).digest()
        found: str | None = None
        for stored, tenant in self._entries():
            if hmac.compare_digest(stored, digest):
                found = tenant
        return found

    def __bool__(self) -> bool:
        return bool(self._entries())
