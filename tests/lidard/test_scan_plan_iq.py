"""The I/Q receiver in the configuration and the scan plan (issue 14 item 2): which channels are
recorded, which Doppler band the DSP searches (a band, not a prior), what it refuses and why."""

import pytest

from lidard.config import ConfigError, load_config
from lidard.instrument import ScanRequest
from lidard.instrument.scan_loop import plan_scan, speed_span_mps
from tests.helpers.tolerances import NOMINAL_ENV


def cfg(**env):
    return load_config("config/sim_iq.toml", environ={**NOMINAL_ENV, **env})


def test_iq_plan_records_i_and_q_and_searches_the_doppler_band_without_a_prior():
    c = cfg()
    assert c.adc.iq and c.chirp.shape == "triangle"
    p = plan_scan(c, c.optics(), ScanRequest(pattern="roi", rows=(0, 2), cols=(0, 2), max_range_m=2.0),
                  iq_imbalance=(1.05, 0.03))
    assert p.acquisition.channels == ("beat_i", "beat_q")
    assert p.dsp.iq and (p.dsp.iq_gain, p.dsp.iq_phase_rad) == (1.05, 0.03)
    assert p.dsp.cw_samples == 0
    # the band is the scan's max_speed_mps (config/sim_iq.toml: 10 m/s), searched as a band
    assert speed_span_mps(c) == c.scan.max_speed_mps == 10.0 == p.dsp.max_speed_mps
    # a record covers the band: its rate grows with the requested band
    p2 = plan_scan(c, c.optics(), ScanRequest(pattern="roi", rows=(0, 2), cols=(0, 2), max_range_m=2.0,
                                              max_speed_mps=20.0))
    assert p2.dsp.max_speed_mps == 20.0 and p2.adc.fs_hz > p.adc.fs_hz


def test_iq_with_the_three_segment_chirp_is_refused_naming_both_keys():
    with pytest.raises(ConfigError, match=r"adc.iq = true.*chirp.shape"):
        load_config("config/sim.toml", environ={**NOMINAL_ENV, "LIDARD__ADC__IQ": "true"})


def test_phase_noise_compensation_records_the_monitor_beside_i_and_q():
    c = cfg()
    far = ScanRequest(pattern="roi", rows=(0, 2), cols=(0, 2), max_range_m=200.0)
    p = plan_scan(c, c.optics(), far)                      # "auto" at 200 m: on
    assert p.phase_noise and p.acquisition.channels == ("beat_i", "beat_q", "mzi")
    quad = cfg(LIDARD__MONITOR__QUADRATURE="true")
    assert plan_scan(quad, quad.optics(), far).acquisition.channels == ("beat_i", "beat_q", "mzi", "mzi_q")
    near = ScanRequest(pattern="roi", rows=(0, 2), cols=(0, 2), max_range_m=2.0)
    assert plan_scan(c, c.optics(), near).acquisition.channels == ("beat_i", "beat_q")
