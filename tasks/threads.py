"""Per-item work on a few threads, results in the items' order: numpy, OpenCV and SciPy release the GIL
in their loops, so per-frame work that does not depend on the other frames' results uses both cores of a
small machine, and the consumer sees the same results in the same order as on one thread (the same bytes
out, whatever the thread count)."""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

THREADS = min(2, os.cpu_count() or 1)
"""Threads per stage: two (rooms already run in parallel in a building run)."""

_T = TypeVar("_T")
_R = TypeVar("_R")


def imap_ordered(
    work: Callable[[_T], _R], items: Iterable[_T], threads: int = THREADS, ahead: int = 0
) -> Iterator[_R]:
    """`work(item)` for every item, yielded in the items' order, computed on up to `threads` threads with
    at most `ahead` (default twice the threads) items in flight, so that a stream of frames stays a stream
    (bounded memory). The items are drawn (e.g. decoded) on the calling thread. `work` must touch nothing
    another call writes."""
    if threads <= 1:
        yield from map(work, items)
        return
    ahead = ahead or 2 * threads
    with ThreadPoolExecutor(threads) as pool:
        pending: deque[Future[_R]] = deque()
        for item in items:
            pending.append(pool.submit(work, item))
            if len(pending) >= ahead:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
