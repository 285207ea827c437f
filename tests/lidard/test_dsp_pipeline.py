"""The DSP worker pipeline of a scan (lidard.instrument.pipeline): results in submission order whatever
order the workers finish in, a bounded queue (the reads wait when the DSP falls behind), a worker's error
at its place in the order (and nothing of it kept once handed out), and the points identical to the serial
DSP's, in pixel order."""

import gc
import threading
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest
from lidard.instrument.pipeline import DspPipeline
from lidard.instrument.points import PointBuffer, RawBatch
from lidard.instrument.scan_loop import plan_scan
from tests.helpers.deadlines import WAIT_S  # a deadline for a hung test
from tests.helpers.tolerances import NOMINAL_ENV


def test_results_come_back_in_submission_order_when_later_jobs_finish_first():
    gates = {i: threading.Event() for i in range(6)}
    done = {i: threading.Event() for i in range(6)}

    def fn(i):
        assert gates[i].wait(WAIT_S)
        done[i].set()
        return i * 10

    pipe = DspPipeline(fn, workers=3, depth=3)
    for i in range(3):        # three workers, one job each
        pipe.submit(i)
    for i in (2, 1):          # the later ones finish first
        gates[i].set()
        assert done[i].wait(WAIT_S)
    assert pipe.ready() == []                    # job 0 still runs: nothing may be handed out yet
    for i in range(3, 6):
        gates[i].set()
        pipe.submit(i)
    for i in range(3, 6):
        assert done[i].wait(WAIT_S)
    assert pipe.ready() == [] and not done[0].is_set()
    gates[0].set()
    assert pipe.ready(wait=True) == [0, 10, 20, 30, 40, 50]
    pipe.close()


def test_the_queue_is_bounded_so_the_reader_waits_for_the_dsp():
    release = threading.Event()
    pipe = DspPipeline(lambda j: release.wait(WAIT_S) and j, workers=1, depth=1)
    pipe.submit("a")          # running (blocked)
    pipe.submit("b")          # waiting in the queue
    third = threading.Thread(target=pipe.submit, args=("c",), daemon=True)
    third.start()
    third.join(0.5)
    assert third.is_alive(), "a third batch was taken while one ran and one waited"
    assert pipe.in_flight == 2
    release.set()
    third.join(WAIT_S)
    assert not third.is_alive() and pipe.ready(wait=True) == ["a", "b", "c"]
    pipe.close()


def test_an_error_comes_after_the_results_before_it_and_the_later_ones_are_kept():
    def fn(j):
        if j == 2:
            raise ValueError("bad batch 2")
        return j

    pipe = DspPipeline(fn, workers=2)
    for j in range(5):
        pipe.submit(j)
    got = pipe.ready(wait=True)
    assert got == [0, 1]
    with pytest.raises(ValueError, match="bad batch 2"):
        pipe.ready(wait=True)
    assert pipe.ready(wait=True) == [3, 4]
    pipe.close()
    with pytest.raises(RuntimeError, match="after close"):
        pipe.submit(9)


def _hand_out_and_drop(ready: Callable[[], Any], kept: list[weakref.ref]) -> str:
    """``ready()`` called from a frame that holds a batch's array (as the acquisition's frames do); the
    error it raises is caught and dropped. Its message, for the caller to check."""
    def acquisition():
        batch = np.ones((64, 4096))          # 2 MB: the raw batch the acquisition's frame holds
        kept.append(weakref.ref(batch))
        ready()
    try:
        acquisition()
    except Exception as exc:                 # what the scan loop's handler does: log, drop
        return str(exc)
    raise AssertionError("the failed batch's error was not handed out")


def held_after_error(ready: Callable[[], Any], kept: list[weakref.ref]) -> tuple[str, list[bool]]:
    """With the cyclic collector off (what only a collection would free counts as held): hand out
    the error, drop it, and say which of ``kept`` are still alive. A kept traceback keeps every frame
    it passed through (the failed DSP's, the acquisition's) with their arrays; in a cycle those stay
    until a full collection, minutes apart in a long-running daemon."""
    gc.collect()
    gc.disable()
    try:
        msg = _hand_out_and_drop(ready, kept)
        held = [r() is not None for r in kept]
    finally:
        gc.enable()
    return msg, held


def test_a_failed_batchs_arrays_are_freed_once_its_error_is_handed_out():
    kept: list[weakref.ref] = []

    def fn(j):
        records = np.ones((64, 4096))        # the DSP's working arrays, held by its frame
        if j == 1:
            kept.append(weakref.ref(records))
            raise ValueError(f"bad batch {j} after {records.shape[0]} records")
        return j

    pipe = DspPipeline(fn, workers=2)
    for j in range(3):
        pipe.submit(j)
    assert pipe.ready(wait=True) == [0]
    msg, held = held_after_error(lambda: pipe.ready(wait=True), kept)
    assert msg == "bad batch 1 after 64 records" and len(held) == 2
    assert held == [False, False], "the failed batch's arrays outlive its handed-out error"
    assert pipe.ready(wait=True) == [2]      # the pipeline goes on: the later results are kept
    pipe.close()


def test_an_error_kept_behind_earlier_results_is_not_kept_once_raised():
    # ready(wait=True) hands out the result before the failed batch and keeps the error for its next call
    kept: list[weakref.ref] = []

    def fn(j):
        if j == 0:
            return j
        records = np.ones((64, 4096))
        kept.append(weakref.ref(records))
        raise ValueError(f"bad batch {j}")

    pipe = DspPipeline(fn, workers=2)
    pipe.submit(0)
    pipe.submit(1)
    assert pipe.ready(wait=True) == [0]
    assert pipe._error is not None
    msg, held = held_after_error(pipe.ready, kept)
    assert msg == "bad batch 1" and held == [False, False]
    assert pipe._error is None
    pipe.close()

def _batches(p, n_batches, px_per_batch, rng):
    """Raw batches of a plan: a tone per pixel at a pixel-dependent beat, white noise, int16 codes."""
    rl, avg = p.adc.record_length, p.averages
    t = np.arange(rl) / p.adc.fs_hz
    out = []
    for b in range(n_batches):
        f = 1e5 + 4e3 * (b * px_per_batch + np.arange(px_per_batch))     # a range each, 0.14-1.7 m
        x = 2000 * np.cos(2 * np.pi * f[:, None, None] * t) + rng.normal(0, 30, (px_per_batch, avg, rl))
        pixels = np.stack([np.full(px_per_batch, 40 + b), np.arange(px_per_batch)], axis=1)
        out.append(RawBatch(np.round(x).astype(np.int16), pixels, b * 1e-3 + np.arange(px_per_batch) * 1e-5,
                            np.zeros(px_per_batch, bool)))
    return out


def test_the_points_with_dsp_workers_are_the_serial_dsps_in_pixel_order():
    # the triangle: a static target is one tone on both ramps (no constant segment to model here)
    cfg = load_config("config/sim.toml", environ={**NOMINAL_ENV, "LIDARD__CHIRP__SHAPE": "triangle"})
    optics = cfg.optics()
    p = plan_scan(cfg, optics, ScanRequest(pattern="roi", rows=(40, 52), cols=(0, 24), averages=2))
    batches = _batches(p, 12, 24, np.random.default_rng(7))
    got = {}
    for workers in (0, 3):
        pb = PointBuffer(p.dsp, optics, lsb_v=p.lsb_v, mzi_delay_s=p.mzi_delay_s, flush_bytes=40_000,
                         workers=workers)
        for i, b in enumerate(batches):
            pb.add(b, last=i == len(batches) - 1)
        got[workers] = pb.points()
    serial, piped = got[0], got[3]
    assert len(serial) >= 12 * 24 and serial.dtype == piped.dtype
    assert all(np.array_equal(serial[k], piped[k], equal_nan=True) for k in serial.dtype.names)
    assert np.all(np.diff(piped["t"]) >= 0)          # merged in pixel order
    # and the points are the tones': range = c f / (2 kappa) within a range bin
    f = 1e5 + 4e3 * ((piped["row"].astype(int) - 40) * 24 + piped["col"])
    first = piped["return_index"] == 0
    r_true = 299_792_458.0 * f / (2 * cfg.chirp.rate_hz_per_s)
    assert np.max(np.abs(piped["range"][first] - r_true[first])) < p.dsp.range_resolution_m


def test_a_scan_that_fails_before_its_result_still_ends_its_dsp_workers(monkeypatch):
    # the outputs cannot come up: no result is computed, the DSP threads must not be left waiting
    from lidard.config import load_config as _load
    from lidard.instrument import open_instrument
    cfg = _load("config/sim.toml", environ=NOMINAL_ENV)
    inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    try:
        def refuse():
            raise RuntimeError("laser refused")
        monkeypatch.setattr(inst.safety, "bring_up", refuse)
        before = {t.name for t in threading.enumerate() if t.name.startswith("lidard-dsp")}
        with pytest.raises(RuntimeError, match="laser refused"):
            inst.run_scan(ScanRequest(pattern="roi", rows=(40, 42), cols=(40, 44)), lambda p: None, threading.Event())
        after = {t.name for t in threading.enumerate() if t.name.startswith("lidard-dsp")}
        assert not before and not after
    finally:
        inst.close()
