"""The DSP's worker processes (lidard.dsp_pool, ProcessDspPipeline): the serial DSP's points
bit for bit and in pixel order, a batch's error at its place, the samples held bounded by the slots,
one pool per process reused scan after scan (no thread or process per scan), a dead worker replaced,
Ctrl-C left to the acquiring process, and a second user at the same time sent to threads."""

import os
import signal
import threading
import weakref

import numpy as np
import pytest

from lidard.config import load_config
from lidard import dsp_pool
from lidard.instrument import ScanRequest
from lidard.instrument.pipeline import DspPipeline, ProcessDspPipeline
from lidard.instrument.points import PointBuffer, RawBatch
from lidard.instrument.scan_loop import plan_scan
from tests.helpers.tolerances import NOMINAL_ENV
from tests.lidard.test_dsp_pipeline import _batches, held_after_error

pytestmark = pytest.mark.skipif(dsp_pool.pool_workers() < 2, reason="needs 2 cores (one core: threads, tested apart)")


@pytest.fixture(scope="module")
def plan():
    cfg = load_config("config/sim.toml", environ={**NOMINAL_ENV, "LIDARD__CHIRP__SHAPE": "triangle"})
    optics = cfg.optics()
    return cfg, optics, plan_scan(cfg, optics, ScanRequest(pattern="roi", rows=(40, 52), cols=(0, 24), averages=2))


def _buffer(plan, **kw):
    _, optics, p = plan
    return PointBuffer(p.dsp, optics, lsb_v=p.lsb_v, mzi_delay_s=p.mzi_delay_s, flush_bytes=40_000, **kw)


def test_the_worker_processes_give_the_serial_dsps_points_bit_for_bit_in_pixel_order(plan):
    cfg, _, p = plan
    batches = _batches(p, 12, 24, np.random.default_rng(7))
    got = {}
    for kw in ({"workers": 0}, {"workers": 2, "processes": True}):
        pb = _buffer(plan, **kw)
        assert isinstance(pb._pipe, ProcessDspPipeline) == bool(kw.get("processes"))
        for i, b in enumerate(batches):
            pb.add(b, last=i == len(batches) - 1)
        got[bool(kw.get("processes"))] = pb.points()
    serial, procs = got[False], got[True]
    assert len(serial) >= 12 * 24 and serial.dtype == procs.dtype
    assert all(np.array_equal(serial[k], procs[k], equal_nan=True) for k in serial.dtype.names)
    assert np.all(np.diff(procs["t"]) >= 0)
    # the points are the tones': range = c f / (2 kappa) within a range bin
    f = 1e5 + 4e3 * ((procs["row"].astype(int) - 40) * 24 + procs["col"])
    first = procs["return_index"] == 0
    r_true = 299_792_458.0 * f / (2 * cfg.chirp.rate_hz_per_s)
    assert np.max(np.abs(procs["range"][first] - r_true[first])) < p.dsp.range_resolution_m


def _fed_with_a_bad_batch(plan, n: int, bad: int, seed: int) -> tuple[PointBuffer, ProcessDspPipeline]:
    """A buffer on the worker processes fed ``n`` batches of rows 40, 41, ...; batch ``bad`` has too short
    a record (its DSP raises)."""
    _, _, p = plan
    batches = _batches(p, n, 24, np.random.default_rng(seed))
    b = batches[bad]
    batches[bad] = RawBatch(b.beat[:, :, :10], b.pixels, b.t_pix_s, b.clipped)
    pb = _buffer(plan, workers=2, processes=True)
    assert isinstance(pb._pipe, ProcessDspPipeline)
    for b in batches:
        pb._pending.append(b)
        pb.flush()
    return pb, pb._pipe


def test_a_failing_batch_raises_at_its_place_and_the_others_keep_their_points(plan):
    pb, pipe = _fed_with_a_bad_batch(plan, 5, 2, seed=3)
    got = pipe.ready(wait=True)
    assert [int(g["row"][0]) for g in got] == [40, 41]         # the two before it, in order
    with pytest.raises(ValueError, match="beat must be"):
        pipe.ready(wait=True)
    assert [int(g["row"][0]) for g in pipe.ready(wait=True)] == [43, 44]
    pb.close()


def test_a_failed_batchs_error_keeps_no_frame_once_handed_out(plan):
    # the worker's error comes back pickled (no frames); raised here, its traceback takes the
    # acquisition's frames, which must not stay tied to the pipeline once the caller has dropped it
    pb, pipe = _fed_with_a_bad_batch(plan, 3, 1, seed=5)
    assert [int(g["row"][0]) for g in pipe.ready(wait=True)] == [40]
    kept: list[weakref.ref] = []
    msg, held = held_after_error(pipe.ready, kept)
    assert "beat must be" in msg and held == [False]
    assert [int(g["row"][0]) for g in pipe.ready(wait=True)] == [42]
    pb.close()


def test_the_samples_in_the_workers_are_bounded_by_the_slots(plan):
    # however far the DSP falls behind, at most 2 batches a worker are in shared memory
    _, _, p = plan
    pb = _buffer(plan, workers=2, processes=True)
    pipe = pb._pipe
    cap = 2 * len(dsp_pool.dsp_pool().workers)
    most = 0
    batches = _batches(p, 16, 24, np.random.default_rng(5))
    for b in batches:
        pb._pending.append(b)
        pb.flush()
        most = max(most, len(pipe._busy) + len(pipe._free))
    assert 2 <= most <= cap
    pts = pb.points()
    assert pipe.in_flight == 0 and not pipe._free          # every slot freed once the scan's DSP is done
    serial = _buffer(plan, workers=0)
    for b in batches:
        serial.add(b)
    assert serial.points().tobytes() == pts.tobytes()


def test_a_second_user_at_the_same_time_gets_threads(plan):
    first = _buffer(plan, workers=2, processes=True)
    second = _buffer(plan, workers=2, processes=True)
    assert isinstance(first._pipe, ProcessDspPipeline) and isinstance(second._pipe, DspPipeline)
    first.points()
    second.points()
    third = _buffer(plan, workers=2, processes=True)      # the pool is free again once the first closed
    assert isinstance(third._pipe, ProcessDspPipeline)
    third.points()


def test_a_dead_worker_is_replaced_and_ctrl_c_is_left_to_the_acquiring_process(plan):
    _, _, p = plan
    pool = dsp_pool.dsp_pool()
    os.kill(pool.workers[0].proc.pid, signal.SIGINT)        # ignored: the scan decides what Ctrl-C stops
    pb = _buffer(plan, workers=2, processes=True)
    for b in _batches(p, 4, 24, np.random.default_rng(1)):
        pb.add(b)
    assert len(pb.points()) >= 4 * 24 and pool.alive()
    pool.workers[1].proc.kill()
    pool.workers[1].proc.join(10)
    fresh = dsp_pool.dsp_pool()
    assert fresh is not pool and fresh.alive() and set(fresh.pids).isdisjoint(pool.pids)
    pb = _buffer(plan, workers=2, processes=True)
    for b in _batches(p, 4, 24, np.random.default_rng(1)):
        pb.add(b)
    assert len(pb.points()) >= 4 * 24


def test_the_workers_run_below_the_acquiring_process():
    # the scan's serial chain (reads, transport, safety check) gets a busy machine's cores first
    pool = dsp_pool.dsp_pool()
    assert sorted(pool.map(os.getpid, [()] * len(pool.workers))) == sorted(pool.pids)   # each one serving
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    assert [os.getpriority(os.PRIO_PROCESS, pid) for pid in pool.pids] == \
        [min(19, mine + dsp_pool.WORKER_NICE)] * len(pool.workers)


def test_a_worker_that_dies_under_a_batch_fails_that_batch_with_a_clear_error(plan):
    _, _, p = plan
    pb = _buffer(plan, workers=2, processes=True)
    pipe = pb._pipe
    pool = dsp_pool.dsp_pool()
    for w in pool.workers:
        w.proc.kill()
        w.proc.join(10)
    with pytest.raises(dsp_pool.DspWorkerLost, match="DSP worker"):
        for b in _batches(p, 3, 24, np.random.default_rng(2)):
            pb._pending.append(b)
            pb.flush()
        pipe.ready(wait=True)
    pb.close()
    assert dsp_pool.dsp_pool().alive()


@pytest.mark.slow
def test_scans_in_one_process_reuse_one_pool_and_start_no_thread():
    # three scans of several DSP batches each on the embedded bench: after the first, no thread and
    # no process is added and the same workers run the DSP
    from lidard.instrument import open_instrument
    cfg = load_config("config/sim.toml", environ=NOMINAL_ENV)
    inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    req = ScanRequest(pattern="roi", rows=(40, 44), cols=(0, 128), averages=10, max_range_m=2.0)
    try:
        res, threads, pids = [], [], []
        for _ in range(3):
            res.append(inst.run_scan(req, lambda p: None, threading.Event()))
            threads.append(sorted(t.name for t in threading.enumerate()))
            pids.append(dsp_pool.dsp_pool().pids)
    finally:
        inst.close()
    assert threads[0] == threads[1] == threads[2]
    assert not any(t.startswith("lidard-dsp") for t in threads[0])
    assert pids[0] == pids[1] == pids[2]
    assert [(r.partial, r.pixels_scanned, r.pixels_planned) for r in res] == [(False, 384, 384)] * 3     # the bonded pixels of 4 rows
    assert all(len(r.points) >= 192 for r in res)


def test_a_ctrl_c_while_a_batch_is_sent_loses_no_earlier_batch_and_replaces_the_pool(plan, monkeypatch):
    # the earlier batches' points are kept in order; the interrupted one's slot is never reused and the
    # pool, whose pipe may be out of step, is not handed to the next user
    _, _, p = plan
    batches = _batches(p, 4, 24, np.random.default_rng(4))
    pb = _buffer(plan, workers=2, processes=True)
    pipe, pool = pb._pipe, dsp_pool.dsp_pool()
    for b in batches[:3]:
        pb._pending.append(b)
        pb.flush()
    real_send = pool.send

    def interrupted(w, msg):
        if msg[0] == "batch":
            raise KeyboardInterrupt
        return real_send(w, msg)

    monkeypatch.setattr(pool, "send", interrupted)
    pb._pending.append(batches[3])
    with pytest.raises(KeyboardInterrupt):
        pb.flush()
    monkeypatch.setattr(pool, "send", real_send)
    pts = pb.points()
    assert sorted(np.unique(pts["row"])) == [40, 41, 42] and pipe.in_flight == 0
    assert pool.broken and dsp_pool.dsp_pool() is not pool
