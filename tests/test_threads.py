"""tasks.threads: per-item work on threads, results in order, a bounded number in flight."""

from __future__ import annotations

import threading
import time

import pytest

from tasks.threads import imap_ordered


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_results_come_in_the_items_order(threads):
    # later items finish first; the results still come in the items' order
    def work(k: int) -> int:
        time.sleep(0.002 * (10 - k % 10))
        return k * k

    assert list(imap_ordered(work, range(25), threads)) == [k * k for k in range(25)]


def test_items_in_flight_are_bounded():
    """A stream stays a stream: never more than `ahead` items drawn and not yet consumed."""
    drawn = consumed = 0
    most = 0
    lock = threading.Lock()

    def items():
        nonlocal drawn, most
        for k in range(40):
            with lock:
                drawn += 1
                most = max(most, drawn - consumed)
            yield k

    for _ in imap_ordered(lambda k: k, items(), threads=2, ahead=3):
        consumed += 1
    assert consumed == 40 and most <= 3


def test_an_error_in_the_work_reaches_the_caller():
    def work(k: int) -> int:
        if k == 7:
            raise ValueError("frame 7 is broken")
        return k

    with pytest.raises(ValueError, match="frame 7"):
        list(imap_ordered(work, range(20), threads=2))
