"""A one-shot command tells its instrument the scan before anything else runs
(LidarInstrument.expect_scan): the DSP's worker processes start when the scan's batches will go to
them, and the simulated bench loads its compiled synthesis kernels when that scan alone pays for them
(sim_devices.world.synth_jit.load_ahead), both beside the command's set-up. The samples announced must
be the ones the digitizer is then armed with, which the ARM counts toward the same break-even
(synth_jit.expect)."""

from __future__ import annotations

import threading

import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, facade, open_instrument
from sim_devices.world import synth_jit

SMALL = ScanRequest(pattern="roi", rows=(40, 42), cols=(0, 8))           # 16 pixels: one DSP batch
REGION = ScanRequest(pattern="roi", rows=(40, 72), cols=(0, 128), averages=10, max_range_m=2.0)


@pytest.fixture(autouse=True)
def no_pool(monkeypatch):
    started = []
    monkeypatch.setattr(facade, "warm_in_background", lambda: started.append(1))
    return started


@pytest.fixture(scope="module")
def inst():
    i = open_instrument(load_config("config/sim.toml"), scene_path="config/scenes/empty.toml", bench="embedded")
    try:
        yield i
    finally:
        i.close()


@pytest.mark.parametrize("averages, max_range_m", [(2, 2.0), (3, 6.0)])
def test_expect_scan_announces_the_samples_the_digitizer_is_armed_with(inst, monkeypatch, averages, max_range_m):
    announced, armed = [], []
    monkeypatch.setattr(synth_jit, "load_ahead", lambda samples: announced.append(samples) or False)
    monkeypatch.setattr(synth_jit, "expect", lambda samples: armed.append(samples))
    req = ScanRequest(pattern="roi", rows=(40, 42), cols=(0, 8), averages=averages, max_range_m=max_range_m)
    assert inst.expect_scan(req) is False          # one DSP batch, and the bench answered "nothing started"
    inst.run_scan(req, lambda p: None, threading.Event())
    assert len(announced) == 1 and armed[-1:] == announced
    assert announced[0] > 0


def test_expect_scan_passes_on_what_the_bench_started(inst, monkeypatch):
    monkeypatch.setattr(synth_jit, "load_ahead", lambda samples: True)
    assert inst.expect_scan(SMALL) is True


@pytest.mark.parametrize("cores, req, pool", [(2, REGION, 1), (1, REGION, 0), (4, SMALL, 0)])
def test_expect_scan_starts_the_dsp_processes_when_the_scan_uses_them(inst, monkeypatch, no_pool, cores, req, pool):
    monkeypatch.setattr(facade, "pool_workers", lambda: cores)
    monkeypatch.setattr(synth_jit, "load_ahead", lambda samples: False)
    assert inst.expect_scan(req) is bool(pool)
    assert len(no_pool) == pool


def test_expect_scan_without_a_simulated_bench_only_starts_the_dsp_processes(inst, monkeypatch, no_pool):
    called = []
    monkeypatch.setattr(synth_jit, "load_ahead", lambda samples: called.append(samples) or True)
    monkeypatch.setattr(inst, "_sim", None)        # what real hardware has: no bench hooks
    monkeypatch.setattr(facade, "pool_workers", lambda: 2)
    assert inst.expect_scan(SMALL) is False
    assert inst.expect_scan(REGION) is True and len(no_pool) == 1
    assert called == []
