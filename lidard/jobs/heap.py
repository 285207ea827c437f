"""A long-running daemon's memory: freed heap memory goes back to the system after every job of the
scan worker, and the daemon's arrays are not backed by transparent huge pages.

A scan allocates and frees tens of MB of numpy temporaries and many small objects on several threads
(the worker, the HTTP server's thread pool). glibc's allocator keeps freed memory in per-thread
arenas and returns it to the system only from the top of each heap, so a long-running daemon's RSS
creeps up in steps as arenas fill and fragment, although nothing is leaked (measured: ~7 MB freed by
one ``malloc_trim(0)`` after a scan, the same 7 MB in use again ten scans later). ``malloc_trim``
walks every arena and gives back whole free pages; it takes about a millisecond. On other C
libraries (musl, macOS) there is no such call and nothing is done.

numpy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every large array.
That speeds up the first touch of a big one-off array, but in a daemon the arrays come and go in
heap regions that stay marked, and the kernel's khugepaged fills such a region into a whole 2 MB page
even when few of its small pages are in use: measured with benchmarks/soak.py, the daemon held
58 MB more anonymous memory with them, growing in 2 MB steps for as long as it ran. ``lidard``
therefore turns numpy's request off at start (:func:`avoid_huge_pages`), for its child bench too,
unless ``NUMPY_MADVISE_HUGEPAGE`` is set in its environment; one-shot commands keep numpy's default.
"""

from __future__ import annotations

import ctypes
import functools
import os
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


def avoid_huge_pages() -> bool:
    """Stop numpy asking for transparent huge pages in this process and in the processes it starts
    (``NUMPY_MADVISE_HUGEPAGE=0``); False when the environment asks for them, or numpy cannot be told."""
    os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
    if os.environ["NUMPY_MADVISE_HUGEPAGE"] != "0":
        return False
    try:
        from numpy._core.multiarray import _set_madvise_hugepage   # what numpy's import reads the variable into
    except ImportError:
        return False
    _set_madvise_hugepage(False)
    return True
