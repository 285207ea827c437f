"""Scan planning with the quadrature monitor (issue 15): which digitizer channels, which ADC rate, and
what the scan meta records (lidard.instrument.scan_loop)."""

import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest
from lidard.instrument.errors import InstrumentError
from lidard.instrument.scan_loop import adc_plan, plan_scan

TAU_M = 200e-9


def _plan(quadrature: bool, max_range_m: float, mode: str = "on"):
    # the triangle: these plans are about the monitor channels and the rate, not the constant segment
    cfg = load_config("config/sim.toml", environ={"LIDARD__MONITOR__QUADRATURE": str(quadrature).lower(),
                                                  "LIDARD__CHIRP__SHAPE": "triangle"})
    req = ScanRequest(pattern="roi", rows=(60, 62), cols=(60, 62), max_range_m=max_range_m,
                      phase_noise_compensation=mode)
    return cfg, plan_scan(cfg, cfg.optics(), req)


def test_quadrature_records_both_monitor_outputs_on_a_whole_number_of_samples_per_delay():
    for max_range_m in (45.0, 112.6, 150.0, 200.0):
        _, p = _plan(True, max_range_m)
        assert p.quadrature and p.acquisition.channels == ("beat", "mzi", "mzi_q")
        fs = p.adc.fs_hz
        assert fs * TAU_M == pytest.approx(round(fs * TAU_M), abs=1e-6)
        assert p.dsp.fs_hz == fs and p.adc.record_length == 2 * round(fs * 80e-6)


def test_rate_is_raised_only_to_the_next_whole_delay():
    # 30 m with compensation on: the plain plan's rate, ceiled to k / tau_m (never lower, < 1 / tau_m more)
    cfg = load_config("config/sim.toml", environ={"LIDARD__CHIRP__SHAPE": "triangle"})   # its speed prior
    base = adc_plan(cfg, 1.5 * 299_792_458.0 * TAU_M / 2).fs_hz
    fs = adc_plan(cfg, 1.5 * 299_792_458.0 * TAU_M / 2, whole_monitor_delay=True).fs_hz
    assert base <= fs < base + 1 / TAU_M
    cfg_slow = load_config("config/sim.toml", environ={"LIDARD__ADC__MAX_SAMPLE_RATE_HZ": "1.22e8",
                                                       "LIDARD__CHIRP__SHAPE": "triangle"})
    with pytest.raises(InstrumentError, match="adc.max_sample_rate_hz"):
        adc_plan(cfg_slow, 60.0, whole_monitor_delay=True)     # 122 MHz: 24.4 samples per delay, 25 too fast


def test_single_mzi_and_compensation_off_keep_their_channels():
    _, p = _plan(False, 150.0)
    assert not p.quadrature and p.acquisition.channels == ("beat", "mzi")
    _, p = _plan(True, 150.0, mode="off")
    assert not p.quadrature and p.acquisition.channels == ("beat",)
