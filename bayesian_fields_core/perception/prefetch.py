"""A bounded, ordered pipeline of worker threads: decode | segment | crop run ahead of encode.

Each step runs in its own thread and hands its results to the next through a queue of at most
`depth` items, so while the caller encodes frame n the threads are decoding, segmenting and
cropping frames n+1..n+depth, and memory stays bounded by `depth` frames per step however long
the capture is. Order is kept (one thread per step). Image decoding (PIL), numpy and torch
kernels release the GIL, which is where the overlap comes from; each model is called from one
thread only. An exception in a step is re-raised in the caller; leaving the loop early (an error,
a cancel) stops the threads.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

_END = object()
_POLL_SECONDS = 0.1


class _Failure:
    def __init__(self, error: BaseException) -> None:
        self.error = error


def _put(q: queue.Queue, item: Any, stop: threading.Event) -> bool:
    while not stop.is_set():
        try:
            q.put(item, timeout=_POLL_SECONDS)
            return True
        except queue.Full:
            continue
    return False


def _get(q: queue.Queue, stop: threading.Event) -> Any:
    while not stop.is_set():
        try:
            return q.get(timeout=_POLL_SECONDS)
        except queue.Empty:
            continue
    return _END


def _feed(items: Iterable[Any], out: queue.Queue, stop: threading.Event) -> None:
    try:
        for item in items:
            if not _put(out, item, stop):
                return
    except BaseException as error:  # noqa: BLE001 - handed to the caller
        _put(out, _Failure(error), stop)
        return
    _put(out, _END, stop)


def _work(fn: Callable[[Any], Any], inp: queue.Queue, out: queue.Queue, stop: threading.Event) -> None:
    while True:
        item = _get(inp, stop)
        if item is _END or isinstance(item, _Failure):
            _put(out, item, stop)
            return
        try:
            result = fn(item)
        except BaseException as error:  # noqa: BLE001 - handed to the caller
            _put(out, _Failure(error), stop)
            return
        if not _put(out, result, stop):
            return


def pipelined(items: Iterable[Any], steps: list[Callable[[Any], Any]], depth: int) -> Iterator[Any]:
    """Yield `steps[-1](...steps[0](item))` for each item, in order, the steps in threads.

    depth: how many results each step may hold ready for the next (>= 1); 0 runs every step in
    the caller's thread, one item at a time (no threads, no overlap).
    """
    if depth < 0:
        raise ValueError(f"depth must be >= 0, got {depth}")
    if depth == 0:
        for item in items:
            for fn in steps:
                item = fn(item)
            yield item
        return
    stop = threading.Event()
    queues: list[queue.Queue[Any]] = [queue.Queue(maxsize=depth) for _ in range(len(steps) + 1)]
    threads = [threading.Thread(target=_feed, args=(items, queues[0], stop), daemon=True)]
    threads += [
        threading.Thread(target=_work, args=(fn, queues[k], queues[k + 1], stop), daemon=True)
        for k, fn in enumerate(steps)
    ]
    for t in threads:
        t.start()
    try:
        while True:
            item = _get(queues[-1], stop)
            if item is _END:
                return
            if isinstance(item, _Failure):
                raise item.error
            yield item
    finally:
        stop.set()
        for t in threads:
            t.join()
