"""A one-shot command tells the simulated bench about its scan before the bench arms
(LidarInstrument.expect_scan), so the bench loads its compiled synthesis kernels beside the command's
set-up when that scan alone pays for them (sim_devices.world.synth_jit.load_ahead). The samples it
announces must be the ones the digitizer is then armed with, which the ARM counts toward the same
break-even (synth_jit.expect)."""

from __future__ import annotations

import threading

import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from sim_devices.world import synth_jit


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
    assert inst.expect_scan(req) is False          # the bench answered "nothing started"
    inst.run_scan(req, lambda p: None, threading.Event())
    assert len(announced) == 1 and armed[-1:] == announced
    assert announced[0] > 0


def test_expect_scan_passes_on_what_the_bench_started(inst, monkeypatch):
    monkeypatch.setattr(synth_jit, "load_ahead", lambda samples: True)
    assert inst.expect_scan(ScanRequest(pattern="roi", rows=(40, 42), cols=(0, 8))) is True


def test_expect_scan_does_nothing_without_a_simulated_bench(inst, monkeypatch):
    called = []
    monkeypatch.setattr(synth_jit, "load_ahead", lambda samples: called.append(samples) or True)
    monkeypatch.setattr(inst, "_sim", None)        # what real hardware has: no bench hooks
    assert inst.expect_scan(ScanRequest(pattern="roi", rows=(40, 42), cols=(0, 8))) is False
    assert called == []
