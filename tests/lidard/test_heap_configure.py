"""lidard.heap.configure: with glibc's defaults, freeing one large array raises the mmap threshold,
so the next arrays of that size are carved out of the arena heaps (where they fragment and, through
numpy's huge-page request, leave huge-page ranges behind). After configure every large array is a
mapping of its own, unmapped from its first byte to its last when it is freed. Each case runs in a
fresh interpreter (the allocator's settings are per process)."""

from __future__ import annotations

import ctypes
import json
import subprocess
import sys

import pytest

from lidard import heap

PROBE = r"""
import json, sys
import numpy as np
from lidard import heap
if sys.argv[1] == "configure":
    heap.configure()
size = 8 << 20
a = np.ones(size, np.uint8)
del a                           # with the dynamic threshold this raises it to 8 MiB
b = np.ones(size, np.uint8)
addr = b.ctypes.data
del b                           # an array of its own mapping is unmapped here; a carved-out one stays


def mapped(a):
    for line in open("/proc/self/maps"):
        lo, hi = (int(x, 16) for x in line.split()[0].split("-"))
        if lo <= a < hi:
            return line.split()[5:] or ["anonymous"]
    return None
print(json.dumps({"first": mapped(addr), "last": mapped(addr + size - 1)}))
"""

glibc = pytest.mark.skipif(not sys.platform.startswith("linux") or not hasattr(ctypes.CDLL(None), "mallopt"),
                           reason="mallopt is glibc's (the daemon runs on Linux)")


def _mapping(mode: str) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, timeout=120,
                         check=True)
    return json.loads(out.stdout)


@glibc
def test_after_configure_a_freed_large_array_goes_back_to_the_system_whole():
    m = _mapping("configure")
    assert m == {"first": None, "last": None}, m


@glibc
def test_without_configure_glibc_keeps_it_in_a_heap():
    """The control: the default allocator's behaviour that configure removes (the probe can fail)."""
    m = _mapping("default")
    assert m["first"] is not None and m["last"] is not None, m


def test_configure_rejects_a_bad_threshold_or_arena_count():
    with pytest.raises(ValueError, match="mmap_threshold"):
        heap.configure(mmap_threshold=0)
    with pytest.raises(ValueError, match="arena_max"):
        heap.configure(arena_max=0)
    with pytest.raises(ValueError, match="trim_threshold"):
        heap.configure(trim_threshold=0)


REUSE_PROBE = r"""
import json, sys
import numpy as np
from lidard import heap
if sys.argv[1] == "bench":
    heap.configure(mmap_threshold=heap.NUMPY_HUGEPAGE_BYTES, trim_threshold=heap.HEAP_BYTES)
else:
    heap.configure()
size = int(sys.argv[2])
keep = np.ones(1000)            # a small live object below, as in a real heap
a = np.ones(size, np.uint8)
first = a.ctypes.data
del a
def mapped(x):
    for line in open("/proc/self/maps"):
        lo, hi = (int(v, 16) for v in line.split()[0].split("-"))
        if lo <= x < hi:
            return True
    return False
still_mapped = mapped(first)
b = np.ones(size, np.uint8)     # the next read's array of the same size
print(json.dumps({"still_mapped": still_mapped, "same_block": b.ctypes.data == first}))
"""


def _reuse(mode: str, size: int) -> dict:
    out = subprocess.run([sys.executable, "-c", REUSE_PROBE, mode, str(size)], capture_output=True, text=True,
                         timeout=120, check=True)
    return json.loads(out.stdout)


@glibc
def test_bench_policy_reuses_blocks_below_numpys_huge_page_size_and_maps_the_rest():
    """The bench's policy: a freed 2 MiB array stays in the heap and the next one reuses it (no fresh
    pages to fault in); an array numpy advises huge pages on (4 MiB or more) is a mapping of its own,
    gone when freed, so no heap range keeps the huge-page flag."""
    small = _reuse("bench", 2 << 20)
    assert small == {"still_mapped": True, "same_block": True}, small
    large = _reuse("bench", heap.NUMPY_HUGEPAGE_BYTES)
    assert large["still_mapped"] is False, large


@glibc
def test_daemon_policy_maps_a_2_mib_array_of_its_own():
    """The control: under the daemon's 256 KiB threshold the same 2 MiB array is a fresh mapping each
    time (unmapped when freed: its pages are faulted in again by the next one)."""
    m = _reuse("daemon", 2 << 20)
    assert m["still_mapped"] is False, m


def test_idle_trimmer_trims_once_per_idle_spell(monkeypatch):
    calls: list[int] = []
    monkeypatch.setattr(heap, "trim", lambda: calls.append(1) or True)
    work = [0]
    t = heap.IdleTrimmer(lambda: work[0], idle_s=1.0)
    assert t.poll() is False            # nothing done since start: nothing to give back
    work[0] = 5
    assert t.poll() is False            # busy since the previous poll
    assert t.poll() is True             # idle for a whole poll period: trimmed
    assert t.poll() is False            # still idle: already trimmed
    work[0] = 9
    assert t.poll() is False
    work[0] = 12
    assert t.poll() is False            # still busy
    assert t.poll() is True
    assert len(calls) == 2


def test_idle_trimmer_rejects_a_bad_period():
    with pytest.raises(ValueError, match="idle_s"):
        heap.IdleTrimmer(lambda: 0, idle_s=0)
