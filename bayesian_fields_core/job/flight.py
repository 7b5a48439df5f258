"""Single flight for the per-scene caches: concurrent jobs on one scene compute a cache once.

Twenty jobs submitted together on the same scene and model profile all find the perception cache
empty; without coordination each would segment and embed every frame. A stage therefore asks its
runner's `Flight` to *hold* a key naming the cache entries it is about to fill (the content keys,
never a path) before computing them: the first holder computes, the others wait for it, then
look at the cache again and find the frames there. The library defines only the seam: the CLI
runs alone (`NoFlight`), the service's workers hold a Redis lock with a heartbeat
(`bayesian_fields_service.live.single_flight`), so a crashed holder's lock expires and a waiter
takes over, and a waiter gives up waiting after a timeout and computes itself (never a deadlock;
at worst the work the flight would have saved).

Correctness never depends on the flight: cache entries are content-keyed and written whole, so
two jobs that compute the same frame write the same bytes.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from typing import Protocol

from bayesian_fields_core.job.cache_keys import short_hash


class Flight(Protocol):
    """Mutual exclusion on a cache key across processes and hosts."""

    def hold(self, key: str, *, on_wait: Callable[[], None]) -> contextlib.AbstractContextManager[None]:
        """Hold `key` for the body of the ``with``; while another holder has it, wait, calling
        `on_wait` now and then (it may raise, e.g. `CancelledError`, to stop waiting)."""
        ...


class NoFlight:
    """One process alone (the CLI): nothing to wait for."""

    def hold(self, key: str, *, on_wait: Callable[[], None]) -> contextlib.AbstractContextManager[None]:
        return contextlib.nullcontext()


def flight_key(kind: str, keys: Iterable[str]) -> str:
    """The flight of a set of cache entries: ``<kind>:<hash of the sorted keys>`` (the keys already
    carry the cache root, the models' fingerprint and the content digests)."""
    return f"{kind}:{short_hash(sorted(keys))}"


@contextlib.contextmanager
def fill_once(
    flight: Flight, kind: str, keys: list[str], missing: Callable[[], bool], on_wait: Callable[[], None]
) -> Iterator[None]:
    """Run the body under the flight of `keys` when `missing()` says some are not cached yet (a
    fully cached set takes no lock). The body re-reads the cache itself: a waiter finds what the
    holder wrote."""
    if not missing():
        yield
        return
    with flight.hold(flight_key(kind, keys), on_wait=on_wait):
        yield
