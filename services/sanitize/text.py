"""Make stored text safe to serve: strings that cannot be UTF-8 encoded, and internal locations.

Why at read time as well as at the edge: the edge now refuses lone surrogates, but manifests
written before that (or by a future bug) must still be readable, listable and deletable instead
of turning every response that touches them into a 500. And an error message that a worker wrote
may name its temp folders or the bucket's internal keys; clients get the message without them
(the full text stays in the worker's log).
"""

from __future__ import annotations

import re
from typing import Any

#: An absolute POSIX path of two or more components (a worker's temp folder, a mount point...).
_ABS_PATH = re.compile(r"(?<![\w.:/])/(?:[^\s'\"/:,;()<>]+/)+([^\s'\"/:,;()<>]*)")
#: A storage key with its tenant prefix, e.g. ``tenants/acme/scenes/s_.../input/x.png``.
_TENANT_KEY = re.compile(r"\btenants/[A-Za-z0-9][A-Za-z0-9_-]{0,63}/")
#: A path the user sent, quoted after the word "path" (`scene.files.resolve_inside`'s messages:
#: "glTF buffers[0].uri path '/etc/passwd' is absolute"): the user's own text, kept as sent.
_USER_PATH = re.compile(r"""(\bpath (?:'[^']*'|"[^"]*"))""")
#: Bucket names in storage messages ("bucket 'bf-prod'").
_BUCKET = re.compile(r"bucket '[^']*'")


def scrub_text(text: str) -> str:
    """`text` with lone surrogates replaced by U+FFFD (so it always encodes as UTF-8)."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:  # a surrogate pair split in two is still one replacement each
        return text.encode("utf-16", "surrogatepass").decode("utf-16", "replace")


def scrub(value: Any) -> Any:
    """A JSON-like value with every string (keys included) passed through `scrub_text`."""
    if isinstance(value, str):
        return scrub_text(value)
    if isinstance(value, dict):
        return {scrub(k): scrub(v) for k, v in value.items()}
    if isinstance(value, list):
        return [scrub(v) for v in value]
    return value


def redact_locations(message: str) -> str:
    """An error message without absolute paths (only their last component is kept, so
    'images/frame_3.png: ...' style context survives) and without tenant/bucket prefixes.
    A path the user sent (`_USER_PATH`) is kept whole: refusing '/etc/passwd' must say so."""

    def _path(m: re.Match[str]) -> str:
        return m.group(1) or "<path>"

    def _redact(part: str) -> str:
        part = _ABS_PATH.sub(_path, part)
        part = _TENANT_KEY.sub("", part)
        return _BUCKET.sub("the bucket", part)

    parts = _USER_PATH.split(message)  # odd indices: the user's quoted paths
    return "".join(part if i % 2 else _redact(part) for i, part in enumerate(parts))
