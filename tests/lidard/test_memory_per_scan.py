"""A daemon runs for weeks, so what a scan leaves allocated must not pile up. Small ROI scans run in
one process through the daemon's own job code (lidard.jobs.ScanWorker over lidard.store.Store, the
live-point buffers and a progress subscriber per scan, as the API wires them) on an embedded simulated
bench, so the daemon side and the bench side share one interpreter. Bench faults that do not latch
are cycled before the scans as in benchmarks/soak.py (retries, reconnects, re-reads).

tracemalloc snapshots after a warm-up (calibration, caches, first compilations), after N more scans
and after N more: the second N scans may leave at most a small, fixed budget per scan (the bounded
caches settle within the first window), and no single allocation site may keep growing in both
windows. A drive log that kept every run's line changes, or a cache keyed by every record length the
bench ever synthesized, fails it."""

from __future__ import annotations

import gc
import tracemalloc

import pytest

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import open_instrument
from lidard.jobs import ScanWorker
from lidard.live.points import LivePoints
from lidard.store import Store

SCAN = {"pattern": "roi", "rows": (40, 44), "cols": (48, 56), "max_range_m": 2.0}
# faults that leave nothing latched: the scan retries, re-reads or reconnects and ends done
FAULTS = [None, ("serial_drop", {"rate": 1e-3}), None, ("usb_timeout", {"device": "digitizer", "n": 2}),
          None, ("modbus_exception", {"code": 6, "n": 2}), ("serial_disconnect", {"reconnect_after_s": 0.05}),
          None, ("usb_disconnect", {"device": "digitizer", "n": 1})]
WARM, N = 12, 16
BUDGET_PER_SCAN = 8 << 10       # bytes a scan may leave behind once warm (bounded caches still settling)
SITE_GROWTH = 32 << 10          # bytes one allocation site may gain in each window before it counts as a leak


def _sites(before, after) -> dict[str, int]:
    return {str(s.traceback[0]): s.size_diff for s in after.compare_to(before, "lineno") if s.size_diff > 0}


@pytest.mark.slow  # 44 scans on an embedded bench under tracemalloc (~1 min)
def test_per_scan_allocations_do_not_grow(tmp_path):
    from lidard.instrument import ScanRequest
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, bench="embedded")
    store = Store(tmp_path / "data")
    worker = ScanWorker(inst, store, laser=cfg.laser, max_queue=1, optics=cfg.optics(),
                        recalibrate_delta_c=cfg.scan.recalibrate_delta_c)
    live = LivePoints()
    worker.add_point_listener(live)
    worker.start()
    ends = []
    k = [0]

    def one_scan() -> None:
        fault = FAULTS[k[0] % len(FAULTS)]
        k[0] += 1
        if fault is not None:
            inst.inject_fault(fault[0], **fault[1])
        rec = worker.submit_scan(ScanRequest(**SCAN))

        def follow(ev: dict) -> None:        # what the SSE endpoint does with each event
            if ev["event"] == "end":
                ends.append(ev["state"])
        unsubscribe = worker.subscribe(rec.id, follow)
        final = worker.wait(rec.id, timeout_s=300)
        unsubscribe()
        inst.clear_faults()
        assert final.state == "done", (fault, final.state, final.error)

    try:
        for _ in range(WARM):
            one_scan()
        tracemalloc.start(1)
        try:
            gc.collect()
            a = tracemalloc.take_snapshot()
            for _ in range(N):
                one_scan()
            gc.collect()
            b = tracemalloc.take_snapshot()
            for _ in range(N):
                one_scan()
            gc.collect()
            c = tracemalloc.take_snapshot()
        finally:
            tracemalloc.stop()
    finally:
        worker.stop()
        store.close()
        inst.close()
    assert len(ends) == WARM + 2 * N and set(ends) == {"done"}
    first, second = _sites(a, b), _sites(b, c)
    total_second = sum(s.size_diff for s in c.compare_to(b, "lineno"))
    report = sorted(second.items(), key=lambda kv: -kv[1])[:8]
    assert total_second <= N * BUDGET_PER_SCAN, (total_second, report)
    leaking = {site: (first.get(site, 0), grew) for site, grew in second.items()
               if grew > SITE_GROWTH and first.get(site, 0) > SITE_GROWTH}
    assert not leaking, leaking
