"""Redis replies as text.

The service's Redis clients are made without ``decode_responses``, so replies are bytes; redis-py
types them ``bytes | str`` (it cannot know how the client was made). `text` decodes bytes and lets
a str through, so the code reads the same whichever way a client was built.
"""

from __future__ import annotations


def text(value: bytes | str, errors: str = "strict") -> str:
    """`value` decoded as UTF-8 when it is bytes (`errors` as in `bytes.decode`), else itself."""
    return value.decode(errors=errors) if isinstance(value, bytes) else value
