"""Scan worker: FIFO, calibration caching, cancel (queued / running, partial kept), failures, events."""


import pytest

from lidard.instrument.types import ScanRequest
from lidard.jobs import QueueFull, ScanWorker, UnknownScan
from lidard.outputs import read_points, read_sidecar
from lidard.store import Store
from tests.helpers.fakes import DeviceFault, FakeInstrument
from tests.helpers.deadlines import WAIT_S

T = WAIT_S  # guard timeout for waits; never reached when things work
SMALL = dict(pattern="roi", rows=(0, 3), cols=(0, 20))   # 3 bonded rows x 20 = 60 pixels


@pytest.fixture
def rig(tmp_path):
    made = []

    def make(**kw):
        inst = FakeInstrument(**kw)
        store = Store(tmp_path / "data")
        w = ScanWorker(inst, store, laser="dfb_default", max_queue=4,
                       progress_interval_s=0.0, meta={"profile": "fpsa128"})
        w.start()
        made.append(w)
        return inst, store, w
    yield make
    for w in made:
        w.stop()


def test_scan_done_files_sidecar_and_calibration_cached(rig):
    inst, store, w = rig()
    a = w.submit_scan(ScanRequest(**SMALL, formats=("ply", "npz")))
    ra = w.wait(a.id, T)
    assert ra.state == "done" and not ra.partial
    assert (ra.points, ra.pixels_scanned, ra.pixels_planned) == (60, 60, 60)
    assert ra.hardware_time_s == pytest.approx(60 * 100e-6)
    assert set(ra.files) == {"ply", "npz"}
    pts = read_points(store.data_dir / ra.files["ply"])
    assert len(pts) == 60 and set(pts["row"].tolist()) == {0, 1, 2}
    side = read_sidecar(store.data_dir / ra.files["ply"])
    assert side["simulated"] is True and side["partial"] is False
    assert side["coverage"] == 1.0 and side["profile"] == "fpsa128"
    assert side["calibration_id"] == ra.calibration_id is not None
    assert side["hardware_time_s"] == pytest.approx(6e-3) and side["wall_time_s"] > 0
    assert side["software_version"] and side["chirp"]["ramp_s"] == 80e-6
    # second scan reuses the stored calibration: linearize ran once
    b = w.submit_scan(ScanRequest(**SMALL))
    assert w.wait(b.id, T).state == "done"
    assert inst.linearize_calls == 1
    assert [c.meta["id"] for c in inst.calibrations_used] == [ra.calibration_id] * 2


def test_fifo_order(rig):
    inst, store, w = rig(hold_after=5)
    first = w.submit_scan(ScanRequest(**SMALL))
    assert inst.reached.wait(T)
    later = [w.submit_scan(ScanRequest(pattern="roi", rows=(0, 1), cols=(k, k + 1))) for k in range(3)]
    assert w.queue_length() == 3
    assert store.get_scan(later[0].id).state == "queued"
    inst.release.set()
    recs = [w.wait(r.id, T) for r in [first, *later]]
    assert all(r.state == "done" for r in recs)
    assert [rq.cols for rq in inst.requests[1:]] == [(0, 1), (1, 2), (2, 3)]
    starts = [r.started for r in recs]
    assert starts == sorted(starts)


def test_queue_limit(rig):
    inst, store, w = rig(hold_after=1)
    w.submit_scan(ScanRequest(**SMALL))
    assert inst.reached.wait(T)
    for _ in range(4):
        w.submit_scan(ScanRequest(**SMALL))
    with pytest.raises(QueueFull, match="queue is full"):
        w.submit_scan(ScanRequest(**SMALL))
    inst.release.set()


def test_cancel_queued_is_immediate_and_never_runs(rig):
    inst, store, w = rig(hold_after=1)
    a = w.submit_scan(ScanRequest(**SMALL))
    assert inst.reached.wait(T)
    b = w.submit_scan(ScanRequest(pattern="roi", rows=(4, 5), cols=(0, 2)))
    rec = w.cancel(b.id)
    assert rec.state == "cancelled" and rec.files == {}
    inst.release.set()
    assert w.wait(a.id, T).state == "done"
    assert all(r.rows != (4, 5) for r in inst.requests)


def test_cancel_running_keeps_partial_points(rig):
    inst, store, w = rig(hold_after=25)
    a = w.submit_scan(ScanRequest(**SMALL, formats=("las",)))
    assert inst.reached.wait(T)
    w.cancel(a.id, reason="interrupted by SIGTERM")
    w.cancel(a.id, reason="a second cancel does not rename the first")
    rec = w.wait(a.id, T)
    assert rec.state == "cancelled" and rec.partial and rec.error is None
    assert (rec.points, rec.pixels_scanned, rec.pixels_planned) == (25, 25, 60)
    pts = read_points(store.data_dir / rec.files["las"])
    assert len(pts) == 25
    side = read_sidecar(store.data_dir / rec.files["las"])
    assert side["partial"] is True and side["coverage"] == pytest.approx(25 / 60)
    assert side["stop_reason"] == "interrupted by SIGTERM"      # why the points stop where they do


def test_failure_stores_device_and_cause(rig):
    try:
        try:
            raise TimeoutError("no trigger within 0.5 s")
        except TimeoutError as cause:
            raise DeviceFault("digitizer: capture failed") from cause
    except DeviceFault as exc:
        err = exc
    inst, store, w = rig(fail_with=err)
    a = w.submit_scan(ScanRequest(**SMALL))
    rec = w.wait(a.id, T)
    assert rec.state == "failed"
    assert "digitizer" in rec.error and "DeviceFault" in rec.error and "no trigger" in rec.error
    assert rec.files == {}


def test_events_progress_then_end(rig):
    inst, store, w = rig(hold_after=1)
    blocker = w.submit_scan(ScanRequest(**SMALL))
    assert inst.reached.wait(T)
    a = w.submit_scan(ScanRequest(**SMALL))
    events = []
    w.subscribe(a.id, events.append)
    inst.hold_after = None
    inst.release.set()
    w.wait(blocker.id, T)
    w.wait(a.id, T)
    kinds = [e["event"] for e in events]
    assert kinds[-1] == "end" and kinds.count("end") == 1
    prog = [e for e in events if e["event"] == "progress"]
    assert len(prog) >= 3
    fr = [e["fraction"] for e in prog]
    assert fr == sorted(fr) and fr[-1] == 1.0
    assert events[-1]["state"] == "done"


def test_calibration_job_goes_through_worker(rig):
    inst, store, w = rig()
    cal = w.submit_calibration().result(T)
    assert inst.linearize_calls == 1
    assert store.latest_calibration("dfb_default").meta["id"] == cal.meta["id"]


def test_calibration_cached_under_configured_laser_name(tmp_path):
    inst = FakeInstrument()
    orig = inst.linearize
    inst.linearize = lambda progress=None: __import__("dataclasses").replace(orig(), laser="DFB-1550 SN42")
    store = Store(tmp_path)
    w = ScanWorker(inst, store, laser="dfb_default", progress_interval_s=0.0)
    w.start()
    try:
        for _ in range(2):
            assert w.wait(w.submit_scan(ScanRequest(**SMALL)).id, T).state == "done"
    finally:
        w.stop()
    assert inst.linearize_calls == 1
    assert store.latest_calibration("dfb_default").meta["reported_laser"] == "DFB-1550 SN42"


def test_stop_interrupts_queued_and_unknown_cancel(rig, tmp_path):
    inst, store, w = rig(hold_after=1)
    a = w.submit_scan(ScanRequest(**SMALL))
    assert inst.reached.wait(T)
    b = w.submit_scan(ScanRequest(**SMALL))
    w.stop(reason="lidard shut down (SIGTERM)")
    assert store.get_scan(b.id).state == "interrupted"
    ra = store.get_scan(a.id)
    assert ra.state == "interrupted" and ra.partial and ra.points == 1
    assert ra.error == "lidard shut down (SIGTERM)"
    assert read_sidecar(store.data_dir / ra.files["ply"])["stop_reason"] == "lidard shut down (SIGTERM)"
    with pytest.raises(UnknownScan):
        w.cancel("0000")


def test_adaptive_scan_runs_coarse_then_dense_where_returns_were(tmp_path):
    from lidard.config import load_profile
    optics = load_profile("fpsa20").optics()
    # a target covering only columns 8..11 and rows 4..7 (one 4x4 cell of the coarse grid)
    inst = FakeInstrument(profile="fpsa20", hit=lambda r, c: 4 <= r < 8 and 8 <= c < 12)
    store = Store(tmp_path)
    w = ScanWorker(inst, store, laser="dfb_default", optics=optics, progress_interval_s=0.0)
    w.start()
    try:
        events = []
        rec = w.submit_scan(ScanRequest(pattern="adaptive", formats=("npz",)))
        w.subscribe(rec.id, events.append)
        assert rec.pixels_planned == 400
        final = w.wait(rec.id, T)
    finally:
        w.stop()
    assert final.state == "done" and not final.partial
    assert [r.pattern for r in inst.requests] == ["pixels", "pixels"]
    coarse, dense = inst.requests
    assert len(coarse.pixels) == 25
    # the hit cell plus its 8 neighbours (rows 0..11, cols 4..15) minus their 9 coarse pixels
    assert len(dense.pixels) == 9 * 16 - 9
    assert all(0 <= r < 12 and 4 <= c < 16 for r, c in dense.pixels)
    assert final.pixels_planned == 25 + 135 and final.pixels_scanned == 160
    pts = read_points(store.data_dir / final.files["npz"])
    assert len(pts) == 16 and set(pts["col"].tolist()) == {8, 9, 10, 11}
    # the dense pass's times follow the coarse pass's
    assert pts["t"].max() >= 25 * 100e-6
    assert [e["event"] for e in events][-1] == "end"


def test_calibration_is_redone_when_the_laser_temperature_moved(tmp_path):
    """A DFB's tuning moves with its temperature: a stored drive is reused within recalibrate_delta_c
    of the temperature it was learned at and re-learned beyond it (the new one is stored)."""
    inst = FakeInstrument()
    store = Store(tmp_path)
    w = ScanWorker(inst, store, laser="dfb_default", progress_interval_s=0.0, recalibrate_delta_c=0.5)
    w.start()
    try:
        def scan():
            assert w.wait(w.submit_scan(ScanRequest(**SMALL)).id, T).state == "done"
        scan()                                  # no calibration yet: learn at 25.0 C
        inst.temperature_c = 25.4
        scan()                                  # 0.4 C away: reused
        assert inst.linearize_calls == 1
        inst.temperature_c = 25.6
        scan()                                  # 0.6 C away: learned again, at 25.6 C
        assert inst.linearize_calls == 2
        assert store.latest_calibration("dfb_default").temperature_c == pytest.approx(25.6)
        inst.temperature_c = float("nan")       # unreadable: the newest calibration is used
        scan()
        assert inst.linearize_calls == 2
        assert inst.calibrations_used[-1].temperature_c == pytest.approx(25.6)
    finally:
        w.stop()


def test_the_worker_gives_freed_heap_back_after_every_job(rig, monkeypatch):
    from lidard import heap
    trims = []
    monkeypatch.setattr(heap, "trim", lambda: trims.append(1) or True)
    inst, store, w = rig()
    for _ in range(2):
        rec = w.wait(w.submit_scan(ScanRequest(**SMALL)).id, T)
        assert rec.state == "done"
    w.stop()                    # joins the worker: every job's clean-up has run
    assert len(trims) == 2


def test_heap_trim_returns_pages_on_glibc():
    import ctypes
    import sys

    from lidard import heap
    if not sys.platform.startswith("linux") or not hasattr(ctypes.CDLL(None), "malloc_trim"):
        assert heap.trim() is False
        return

    def rss_kb() -> int:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
    # 64 MB of 20 kB blocks (below the mmap threshold: they live in the heap), then every other one
    # freed: holes no top-of-heap trim can return, only malloc_trim's walk of the free chunks
    blocks = [bytearray(20_000) for _ in range(3_200)]
    del blocks[::2]
    before = rss_kb()
    assert heap.trim() is True
    assert rss_kb() < before - 8_000, (before, rss_kb())
    del blocks


@pytest.mark.parametrize("warm, setup, started", [(True, {}, 1), (False, {}, 0), (True, None, 0)])
def test_the_worker_starts_the_dsp_processes_unless_told_not_to(tmp_path, monkeypatch, warm, setup, started):
    # a daemon's worker starts them beside its queue; a one-shot command that told its instrument of
    # the scan (Instrument.expect_scan) has started them if the scan needs them; a test double never
    from lidard import dsp_pool
    calls = []
    monkeypatch.setattr(dsp_pool, "warm_in_background", lambda: calls.append(1))
    w = ScanWorker(FakeInstrument(), Store(tmp_path / "data"), laser="dfb_default", setup=setup,
                   warm_dsp_pool=warm)
    w.start()
    w.stop()                    # joins the worker's thread, which decides at its start
    assert len(calls) == started
