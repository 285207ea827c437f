"""The C heap of a long-running process: set up once at its start so a process that runs for weeks
does not creep up, and freed pages handed back after every job of the daemon's scan worker.

Two processes run for as long as the instrument does and allocate alike: the daemon (a scan allocates
and frees tens of MB of numpy temporaries, the DSP's batches are up to 8 MiB, and many small objects on
several threads: the worker, the DSP pipeline's threads, the HTTP server's thread pool) and its
simulated bench, ``lidar-sim`` (every digitizer read synthesizes records of up to tens of MB on the USB
bridge's connection thread and the synthesis pool's threads). With glibc's defaults three things let
such a process's RSS wander by tens of MB although nothing is leaked:

* **The dynamic mmap threshold.** A block above the threshold (128 KiB at start) is its own mapping,
  unmapped when freed; but freeing such a block raises the threshold to its size (up to 32 MiB), so
  from then on the DSP's multi-MB arrays are carved out of the arenas' heaps, where a long-lived small
  object above a freed array pins its pages, and glibc gives memory back only from a heap's top.
* **Huge pages left behind.** numpy asks for transparent huge pages (``madvise``) on every array of
  4 MiB or more. An array carved out of an arena's heap leaves that flag on the heap's range after it is
  freed; the kernel's khugepaged then collapses those ranges back into 2 MiB pages, refilling the holes
  ``malloc_trim`` punched (the 60-minute soak's daemon: ``AnonHugePages`` 39 -> 55 MB and back).
* **One arena per thread**, up to 8 per core: every arena keeps its own free memory.

:func:`configure` therefore fixes the mmap threshold (``M_MMAP_THRESHOLD``: setting it turns the
dynamic adjustment off), so every large array is a mapping of its own that goes back to the system
whole, huge-page flag and all, the moment it is freed; and it bounds the arenas (``M_ARENA_MAX``) to
one per core the process may run on. Call it before the process starts threads. :func:`trim` after a
job walks every arena and gives back whole free pages (about a millisecond; measured ~7 MB freed by one
trim after a scan). On other C libraries (musl, macOS) there are no such calls and nothing is done.

The simulated bench takes other parameters (``configure(mmap_threshold=NUMPY_HUGEPAGE_BYTES,
trim_threshold=HEAP_BYTES)`` and an :class:`IdleTrimmer`) because its allocations differ from the
daemon's: every read allocates and frees hundreds of MB of 0.5-16 MB arrays, nearly all on the two
synthesis threads. Under a 256 KiB threshold each is a fresh mapping whose pages are faulted in again
on every read (0.10-0.13 s of system time per small soak scan against 0.01 s; the default 128 KiB trim
threshold costs the same by giving each heap's top back on every free). With the threshold at numpy's
huge-page size the blocks below it are reused from the heaps read after read, the arrays numpy advises
huge pages on are mappings of their own (no heap range keeps the flag), and a heap's top stays until
the bench goes idle. What the heaps keep is then the largest set of such blocks a read holds at once
(a soak scan's: ~80 MB, the same after every window of scans), handed back by the idle trim.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading
from collections.abc import Callable

# mallopt parameters (glibc's malloc.h)
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
_M_TRIM_THRESHOLD = -1
MMAP_THRESHOLD_BYTES = 256 << 10
"""Blocks of this size or more are mappings of their own (glibc's default starts at 128 KiB and grows
with what is freed). 256 KiB keeps the small and mid-size objects of a scan in the arenas and puts every
record batch, spectrum and point array (tens of kB per pixel, thousands of pixels) in its own mapping."""
NUMPY_HUGEPAGE_BYTES = 4 << 20
"""numpy advises transparent huge pages (``madvise``) on every array of this size or more. As an mmap
threshold it is the smallest that keeps every such array out of the heaps (no heap range is left with
the huge-page flag for khugepaged to refill) while every smaller block is reused from the heaps."""
HEAP_BYTES = 64 << 20
"""The size of a thread arena's heap on 64-bit glibc (HEAP_MAX_SIZE). As a trim threshold: no free
gives a heap's top back; what a heap holds free is reused by the next read, and handed back by
:class:`IdleTrimmer` once the process is idle."""
BENCH_IDLE_S = 2.0
"""How long a simulated bench synthesizes nothing before its freed heap pages go back (a poll period
of :class:`IdleTrimmer`): longer than the gaps between the reads of a scan, shorter than a pause."""


@functools.lru_cache(maxsize=1)
def _libc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None)                    # the C library this process already uses
        trim_fn, mallopt = libc.malloc_trim, libc.mallopt
    except (OSError, AttributeError):
        return None
    trim_fn.argtypes, trim_fn.restype = [ctypes.c_size_t], ctypes.c_int
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return libc


def arenas_for_this_process() -> int:
    """One malloc arena per core this process may run on (its affinity), at least 2."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(2, cores)


def configure(mmap_threshold: int = MMAP_THRESHOLD_BYTES, arena_max: int | None = None,
              trim_threshold: int | None = None) -> bool:
    """Fix glibc's mmap threshold and bound its arenas for a long-running process (see the module's
    docstring); ``trim_threshold`` (bytes, None: glibc's 128 KiB) is how much free memory the top of a
    heap may hold before a free gives it back. False where the C library has no ``mallopt`` (nothing
    changed)."""
    if mmap_threshold <= 0:
        raise ValueError(f"heap.configure: mmap_threshold must be > 0 bytes, got {mmap_threshold!r}")
    if trim_threshold is not None and trim_threshold <= 0:
        raise ValueError(f"heap.configure: trim_threshold must be > 0 bytes, got {trim_threshold!r}")
    arenas = arenas_for_this_process() if arena_max is None else arena_max
    if arenas < 1:
        raise ValueError(f"heap.configure: arena_max must be >= 1, got {arena_max!r}")
    libc = _libc()
    if libc is None:
        return False
    ok = libc.mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    ok = libc.mallopt(_M_ARENA_MAX, int(arenas)) == 1 and ok
    if trim_threshold is not None:
        ok = libc.mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1 and ok
    return ok


_trims = [0]


def trim() -> bool:
    """Return freed heap pages to the system; False where the C library has no ``malloc_trim``."""
    libc = _libc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    _trims[0] += 1
    return True


def trims_done() -> int:
    """How many times :func:`trim` gave this process's freed pages back."""
    return _trims[0]


class _Mallinfo2(ctypes.Structure):
    # glibc's struct mallinfo2 (malloc.h, glibc >= 2.33): every field a size_t
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]


def usage() -> dict[str, int] | None:
    """What the C heap holds now, over all arenas (glibc's ``mallinfo2``): ``arena_bytes`` taken from
    the system for the arenas (the main heap and the threads' heaps), of them ``in_use_bytes`` and
    ``free_kept_bytes`` (freed, still resident or reserved: what a process that does not give memory
    back piles up), ``mmapped_bytes`` in blocks that are mappings of their own. None where the C library
    has no ``mallinfo2`` (musl, macOS, glibc before 2.33)."""
    libc = _libc()
    fn = getattr(libc, "mallinfo2", None) if libc is not None else None
    if fn is None:
        return None
    fn.argtypes, fn.restype = [], _Mallinfo2
    mi = fn()
    return {"arena_bytes": int(mi.arena), "in_use_bytes": int(mi.uordblks), "free_kept_bytes": int(mi.fordblks),
            "mmapped_bytes": int(mi.hblkhd)}


class IdleTrimmer:
    """Gives a process's freed heap pages back once it has gone idle: :meth:`poll` (every ``idle_s``
    seconds from :meth:`run`'s thread) trims when ``activity`` (a counter of the work done, e.g. the
    segments a bench synthesized) has not moved since the previous poll but has moved since the last
    trim. A busy process keeps its freed blocks for the next piece of work (reused without page
    faults); an idle one holds only what is in use."""

    def __init__(self, activity: Callable[[], int], idle_s: float) -> None:
        if not idle_s > 0:
            raise ValueError(f"heap.IdleTrimmer: idle_s must be > 0 s, got {idle_s!r}")
        self.activity = activity
        self.idle_s = float(idle_s)
        self._seen = activity()
        self._trimmed_at = self._seen

    def poll(self) -> bool:
        """Trim if the work stopped since the previous poll and the heap was not trimmed since it
        stopped; True when it trimmed."""
        now = self.activity()
        idle = now == self._seen
        self._seen = now
        if not idle or now == self._trimmed_at:
            return False
        self._trimmed_at = now
        return trim()

    def run(self, stop: threading.Event) -> None:
        """Poll every ``idle_s`` until ``stop`` is set (a thread's target)."""
        while not stop.wait(self.idle_s):
            self.poll()
