"""The three-segment waveform (issue 14): the constant segment's length from the velocity resolution,
the held drive, the trigger period and the records that follow it."""

import numpy as np
import pytest

from lidard.config import ConfigError, load_config
from lidard.instrument.acquisition import AWG_RATE_HZ, drive_for_chirp, plain_drive
from lidard.instrument.errors import InstrumentError
from lidard.instrument.scan_loop import adc_plan
from lidard.physics.chirp import hold_segment_v, three_segment_drive_v, triangle_drive_v


def _cfg(**env):
    return load_config("config/sim.toml", environ={f"LIDARD__CHIRP__{k.upper()}": str(v) for k, v in env.items()})


def test_cw_length_is_the_velocity_resolution_bin():
    for dv in (0.01, 0.05, 0.2):
        c = _cfg(velocity_resolution_mps=dv).chirp
        # one CW bin 1 / T_cw is a Doppler step 2 dv / lambda: T_cw = lambda / (2 dv), to the next us
        assert c.cw_s >= c.wavelength_m / (2 * dv) - 1e-12
        assert c.cw_s - c.wavelength_m / (2 * dv) < 1e-6
        assert c.period_s == pytest.approx(2 * c.ramp_s + c.cw_s)
    assert _cfg(shape="triangle").chirp.cw_s == 0.0 and _cfg(shape="triangle").chirp.period_s == 160e-6


def test_unknown_shape_and_bad_resolution_are_refused():
    with pytest.raises(ConfigError, match="shape"):
        _cfg(shape="sawtooth")
    with pytest.raises(ConfigError, match="velocity_resolution_mps"):
        _cfg(velocity_resolution_mps=0)


def test_drive_holds_between_down_ramp_and_next_up_ramp():
    tri = triangle_drive_v(8.6e9, 80e-6, 100e6, -5e9)
    d = three_segment_drive_v(8.6e9, 80e-6, 78e-6, 100e6, -5e9)
    assert d.size == 23_800 and np.array_equal(d[:16_000], tri)
    assert np.ptp(d[16_000:]) <= np.ptp(tri) / 8000 + 1e-12      # flat: one triangle step at most
    learned = tri + 0.01 * np.sin(np.arange(tri.size) / 700.0)   # a drive that ends off its start
    h = hold_segment_v(learned, 100)
    assert h[16_000] == pytest.approx(learned[-1], abs=np.abs(learned[0] - learned[-1]) / 50)
    assert np.all(np.diff(h[15_999:]) * np.sign(learned[0] - learned[-1]) >= 0)   # a straight line back


def test_drive_for_chirp_completes_a_triangle_and_refuses_other_lengths():
    cfg = _cfg()
    tri = triangle_drive_v(8.6e9, 80e-6, AWG_RATE_HZ, -5e9)
    full = drive_for_chirp(cfg, tri)
    assert full.size == int(round(cfg.chirp.period_s * AWG_RATE_HZ)) and np.array_equal(full[:tri.size], tri)
    assert np.array_equal(drive_for_chirp(cfg, full), full)
    assert plain_drive(cfg, -5e9).size == full.size
    with pytest.raises(InstrumentError, match="relinearize"):
        drive_for_chirp(cfg, tri[:-10])


def _need_hz(cfg, range_m, speed_mps):
    """2.5x Nyquist of the highest beat: f_R(range) + f_D(speed)."""
    return 2.5 * (2 * cfg.chirp.rate_hz_per_s * range_m / 299_792_458 + 2 * speed_mps / 1.55e-6)


def test_record_holds_the_cw_segment_and_the_band_replaces_the_prior():
    three, tri = _cfg(), _cfg(shape="triangle")
    p3, pt = adc_plan(three, 2.0, max_speed_mps=10.0), adc_plan(tri, 2.0)
    assert p3.record_length == 2 * p3.ramp_samples + int(p3.fs_hz * three.chirp.cw_s + 1e-9)
    assert pt.record_length == 2 * pt.ramp_samples
    # the rate holds f_R + f_D(10 m/s) at 2.5x Nyquist: 2.5 (1.43 + 12.9) MHz
    assert p3.fs_hz >= _need_hz(three, 2.0, 10.0)


@pytest.mark.parametrize("speed_mps", [0.1, 0.4, 1.0, 3.0, 10.0, 30.0])
def test_the_requested_speed_sizes_the_record_and_the_default_is_the_config(speed_mps):
    cfg = _cfg()
    p = adc_plan(cfg, 2.0, max_speed_mps=speed_mps)
    # the slowest rate max_rate / k that holds the band: holds it, and the next slower divider would not
    assert _need_hz(cfg, 2.0, speed_mps) <= p.fs_hz
    k = round(cfg.adc.max_sample_rate_hz / p.fs_hz)
    assert cfg.adc.max_sample_rate_hz / (k + 1) < max(_need_hz(cfg, 2.0, speed_mps), cfg.adc.min_sample_rate_hz) \
        or abs(cfg.adc.max_sample_rate_hz / (k + 1) * cfg.chirp.ramp_s % 1) > 1e-6
    assert adc_plan(cfg, 2.0) == adc_plan(cfg, 2.0, max_speed_mps=cfg.scan.max_speed_mps)
    assert cfg.scan.max_speed_mps == 0.4        # config/sim.toml: a static lab scene


def test_the_band_left_in_the_chirp_section_is_refused_naming_its_new_key():
    with pytest.raises(ConfigError, match=r"chirp.doppler_band_mps is now scan.max_speed_mps"):
        _cfg(doppler_band_mps=10.0)
