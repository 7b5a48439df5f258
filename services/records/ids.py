"""The ids the service issues ("s_" scenes, "j_" jobs, "b_" batches): how they are made and the one
pattern every id is checked against.

Why here, at the records' floor: an id is a row's primary key, and the packages that meet ids
(the domains, the API's query parameters, the broker adapter reading stage messages) all sit on or
above the records, so each reads the format from this one place instead of spelling it again.
"""

from __future__ import annotations

import re
import secrets
import time

#: The prefixes of the ids the service issues.
SCENE_ID = "s_"
JOB_ID = "j_"
BATCH_ID = "b_"

#: What follows an id's prefix: the 22 lower-case hex digits `new_id` writes (12 of milliseconds,
#: 10 of randomness).
ID_DIGITS = "[0-9a-f]{22}"


def new_id(prefix: str) -> str:
    """A time-ordered id (ms timestamp in hex, then randomness): listing sorts by creation."""
    return f"{prefix}{int(time.time() * 1000):012x}{secrets.token_hex(5)}"


def id_pattern(prefix: str) -> str:
    """The anchored pattern of the ids `new_id(prefix)` makes, for a FastAPI `Query(pattern=...)`
    (pydantic's regex engine: ``$`` is the end of the text, not before a final newline)."""
    return f"^{re.escape(prefix)}{ID_DIGITS}$"


def is_id(ident: str, prefix: str) -> bool:
    """Whether `ident` is an id `new_id(prefix)` could have made: the one check every id meets
    before it reaches the records (a NUL, a stray byte or a huge value never does)."""
    return re.fullmatch(re.escape(prefix) + ID_DIGITS, ident) is not None


def id_age_s(ident: str) -> float:
    """Seconds since `new_id` made `ident` (0 for an id not in that form)."""
    try:
        return max(0.0, time.time() - int(ident[2:14], 16) / 1000)
    except ValueError:
        return 0.0
