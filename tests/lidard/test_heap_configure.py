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
