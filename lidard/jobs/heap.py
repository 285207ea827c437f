"""Freed heap memory goes back to the system after every job of the scan worker.

A scan allocates and frees tens of MB of numpy temporaries and many small objects on several threads
(the worker, the HTTP server's thread pool). glibc's allocator keeps freed memory in per-thread
arenas and returns it to the system only from the top of each heap, so a long-running daemon's RSS
creeps up in steps as arenas fill and fragment, although nothing is leaked (measured: ~7 MB freed by
one ``malloc_trim(0)`` after a scan, the same 7 MB in use again ten scans later). ``malloc_trim``
walks every arena and gives back whole free pages; it takes about a millisecond. On other C
libraries (musl, macOS) there is no such call and nothing is done.
"""

from __future__ import annotations

import ctypes
import functools
import sys


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None).malloc_trim          # the C library this process already uses
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
    return fn


def trim() -> bool:
    """Return freed heap pages to the system; False where the C library has no ``malloc_trim``."""
    fn = _malloc_trim()
    if fn is None:
        return False
    fn(0)
    return True
