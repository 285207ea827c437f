"""The store's share of a long-running daemon's memory is bounded. SQLite keeps the pages it reads and
writes in a page cache up to ``cache_size``; every scan adds a row (and index entries) to the scans
table, so that cache grows with the number of scans until its bound. A 60-minute soak showed it as a
straight-line creep of the daemon's anonymous memory (0.6-0.8 kB a scan, 2,603 scans); under SQLite's
default bound it stops only at 2000 KiB, after about 4,800 scans. The store sets it to
``PAGE_CACHE_KIB``.

SQLite allocates with its own ``malloc``, which tracemalloc does not see: the bytes are read from the
library itself (``sqlite3_memory_used``, the whole process's SQLite heap) through ctypes, from the
same shared library the ``sqlite3`` module links."""

from __future__ import annotations

import ctypes
import ctypes.util
import time

import pytest

from lidard.store import Store
from lidard.store.database import PAGE_CACHE_KIB

REQUEST = {"pattern": "roi", "rows": [40, 44], "cols": [48, 56], "max_range_m": 2.0, "averages": 1,
           "formats": ["ply"], "label": "x" * 96}     # a row of about the size the soak's scans leave


def _sqlite_heap():
    name = ctypes.util.find_library("sqlite3")
    if name is None:
        pytest.skip("no shared SQLite library to read the heap of (sqlite3 linked statically)")
    lib = ctypes.CDLL(name)
    lib.sqlite3_memory_used.restype = ctypes.c_int64
    return lib.sqlite3_memory_used


def _scans(store: Store, n: int) -> None:
    """What the worker and the API do to the scans table for one small scan."""
    for _ in range(n):
        rec = store.create_scan(REQUEST, pixels_planned=32)
        store.update_scan(rec.id, state="running", started=time.time(), stage="scanning")
        store.update_scan(rec.id, state="done", finished=time.time(), points=32, pixels_scanned=32,
                          files={"ply": f"scans/{rec.id}/scan.ply"}, wall_time_s=1.2345678)
        got = store.get_scan(rec.id)
        assert got is not None and got.state == "done"


@pytest.mark.slow   # 3,000 scans' rows (~3 s)
def test_page_cache_stops_growing_at_its_bound(tmp_path):
    used = _sqlite_heap()
    store = Store(tmp_path)
    try:
        base = used()
        _scans(store, 200)
        first = used() - base
        # the same library the sqlite3 module uses: its heap grew with the rows (pages cached)
        assert first > 200 * 200, first
        _scans(store, 2800)
        grown = used() - base
    finally:
        store.close()
    print(f"SQLite heap after 200 scans' rows: {first / 1024:.0f} KiB, after 3,000: {grown / 1024:.0f} KiB")
    # 3,000 scans' pages (~1.2 MiB under SQLite's default bound) held to the store's bound, plus
    # the page headers and the statement cache
    assert grown <= PAGE_CACHE_KIB * 1024 * 1.25 + (128 << 10), (grown, first)
