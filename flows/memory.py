"""Keeping a run's resident memory to what its running stages hold (glibc's allocator, Linux).

A run computes every room's stages in one process, on pool threads. glibc's malloc gives each thread
that allocates an arena of its own (up to eight per core) and keeps what a finished stage freed inside
them: arrays below its mmap threshold, which it raises to 32 MB after the first large free, come from
those arenas. So after each room the process keeps a little more freed-but-held memory, and its
resident size grows with the number of rooms although only `flow.max_workers` rooms run at once.
Two calls counter that: fewer arenas (`limit_arenas`, at start) and returning the freed pages after each
stage (`release`). Elsewhere (no glibc) both do nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import sys
from collections.abc import Iterator

M_ARENA_MAX = -8
"""mallopt's parameter for the largest number of arenas (glibc malloc.h)."""

_libc: ctypes.CDLL | bool | None = False


def _glibc() -> ctypes.CDLL | None:
    global _libc
    if _libc is False:
        _libc = None
        if sys.platform.startswith("linux"):
            try:
                lib = ctypes.CDLL("libc.so.6")
            except OSError:
                lib = None
            if lib is not None and hasattr(lib, "malloc_trim") and hasattr(lib, "mallopt"):  # glibc
                _libc = lib
    return _libc  # type: ignore[return-value]


def limit_arenas(arenas: int) -> bool:
    """At most `arenas` malloc arenas for threads created from now on; True if set."""
    lib = _glibc()
    return bool(lib is not None and lib.mallopt(M_ARENA_MAX, max(1, int(arenas))) == 1)


def release() -> bool:
    """Return the pages that freed memory leaves unused in every arena to the operating system; True if
    any was returned."""
    lib = _glibc()
    return bool(lib is not None and lib.malloc_trim(0) == 1)


@contextlib.contextmanager
def few_collections() -> Iterator[None]:
    """Python's cyclic collector runs rarely inside, as usual after: for imports (Prefect's: about 8 %
    of their CPU time goes to young collections that find nothing to free among the modules, classes
    and schemas they build, all of which live as long as the process)."""
    usual = gc.get_threshold()
    gc.set_threshold(100_000, 50, 50)
    try:
        yield
    finally:
        gc.set_threshold(*usual)
