"""DFB laser model: FM response (periodic steady state vs causal), tuning presets, phase noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidard.config import LaserPreset, ThermalTerm, load_laser, load_lasers
from sim_devices.world.laser import DfbLaser, ramp_nonlinearity_hz, triangle_drive

EXCURSION_HZ = 8.6e9
RAMP_S = 80e-6


def _plain_triangle(name: str, fs_hz: float = 50e6):
    laser = DfbLaser(load_laser(name))
    drive = triangle_drive(EXCURSION_HZ, RAMP_S, fs_hz, laser.static_tuning_hz_per_v)
    nu = laser.frequency_hz(drive, fs_hz)
    return laser, drive, nu, int(round(RAMP_S * fs_hz))


def test_periodic_steady_state_equals_causal_response_after_many_periods():
    laser = DfbLaser(load_laser("dfb_default"))
    fs = 20e6
    drive = triangle_drive(EXCURSION_HZ, RAMP_S, fs, laser.static_tuning_hz_per_v)
    periodic = laser.frequency_hz(drive, fs)
    # the slowest thermal term (1 ms) needs ~20 time constants to settle: 20 ms = 125 periods
    n_periods = 130
    causal = laser.frequency_hz_causal(np.tile(drive, n_periods), fs).reshape(n_periods, -1)
    exc = np.ptp(periodic)
    assert np.max(np.abs(causal[-1] - periodic)) < 1e-7 * exc
    # ... and the first period, from rest, is visibly different (the test can fail)
    assert np.max(np.abs(causal[0] - periodic)) > 1e-2 * exc


def test_discrete_response_matches_the_continuous_fm_response_at_low_frequency():
    preset = load_laser("dfb_default")
    laser = DfbLaser(preset)
    fs = 1e9
    f = np.array([0.0, 1e3, 6.25e3, 1e5, 1e6, 5e6])
    cont = preset.carrier_hz_per_v + sum(t.gain_hz_per_v / (1 + 2j * np.pi * f * t.tau_s) for t in preset.thermal)
    disc = laser.frequency_response(f, fs)
    # first-order hold discretisation agrees to O((dt/tau)^2) (tau_min = 20 ns, dt = 1 ns), plus the
    # half-sample delay of the hold at high frequency
    assert np.allclose(disc, cont, rtol=3e-4, atol=0)
    assert disc[0].real == pytest.approx(laser.static_tuning_hz_per_v, rel=1e-12)


def test_constant_drive_gives_static_tuning_through_the_nonlinearity():
    preset = load_laser("dfb_strong_nonlinear")
    laser = DfbLaser(preset)
    u0 = 0.4
    nu = laser.frequency_hz(np.full(64, u0), 1e6)
    g = u0 + preset.nonlin_a2 * u0**2 + preset.nonlin_a3 * u0**3
    assert np.allclose(nu, laser.static_tuning_hz_per_v * g, rtol=1e-12)


def test_default_dfb_plain_triangle_rms_nonlinearity_is_half_to_two_percent():
    laser, drive, nu, n_ramp = _plain_triangle("dfb_default")
    assert np.ptp(drive) == pytest.approx(EXCURSION_HZ / abs(laser.static_tuning_hz_per_v))
    exc = np.ptp(nu)
    up, down = ramp_nonlinearity_hz(nu, n_ramp, roi=0.8)
    for rms in (up, down):
        # whichever excursion one normalises by: the achieved swing or the nominal 8.6 GHz
        assert 0.005 <= rms / exc <= 0.02
        assert 0.005 <= rms / EXCURSION_HZ <= 0.02
    # a commercial DFB: thermal tuning dominates and opposes the carrier term
    assert laser.preset.carrier_hz_per_v > 0 > laser.static_tuning_hz_per_v
    # the optical chirp rises during the first half (up ramp) and falls in the second
    assert nu[n_ramp // 2] > nu[0] and nu[3 * n_ramp // 2] < nu[n_ramp]


def test_hard_presets_are_harder_and_ideal_is_ideal():
    _, _, nu_d, n = _plain_triangle("dfb_default")
    base = max(ramp_nonlinearity_hz(nu_d, n)) / np.ptp(nu_d)
    for name in ("dfb_strong_nonlinear", "dfb_slow_thermal"):
        _, _, nu, _ = _plain_triangle(name)
        assert max(ramp_nonlinearity_hz(nu, n)) / np.ptp(nu) > 1.5 * base, name
    presets = load_lasers()
    assert presets["dfb_broad_linewidth"].linewidth_hz > 3 * presets["dfb_default"].linewidth_hz
    laser, _, nu, _ = _plain_triangle("ideal")
    assert laser.linewidth_hz == 0.0 and math.isinf(laser.coherence_time_s)
    assert max(ramp_nonlinearity_hz(nu, n)) < 1e-6 * EXCURSION_HZ
    assert np.ptp(nu) == pytest.approx(EXCURSION_HZ, rel=1e-12)


def test_triangle_drive_shape_and_errors():
    d = triangle_drive(1e9, 10e-6, 1e6, -2e9)
    assert d.size == 20
    assert d[0] == pytest.approx(0.25) and d[10] == pytest.approx(-0.25)   # K < 0: drive falls on the up-chirp
    assert np.allclose(d[1:10], d[19:10:-1])                              # symmetric ramps
    with pytest.raises(ValueError, match="ramp_s"):
        triangle_drive(1e9, 10.5e-6, 1e5, -2e9)                           # 1.05 samples per ramp
    with pytest.raises(ValueError, match="static_tuning"):
        triangle_drive(1e9, 10e-6, 1e6, 0.0)
    with pytest.raises(ValueError, match="excursion_hz"):
        triangle_drive(float("nan"), 10e-6, 1e6, 1e9)


def test_bad_drive_is_rejected():
    laser = DfbLaser(load_laser("dfb_default"))
    with pytest.raises(ValueError, match="NaN"):
        laser.frequency_hz(np.array([0.0, np.nan, 1.0]), 1e6)
    with pytest.raises(ValueError, match="fs_hz"):
        laser.frequency_hz(np.zeros(8), 0.0)
    with pytest.raises(TypeError):
        DfbLaser({"carrier_hz_per_v": 1e9})


def test_phase_noise_increment_variance_and_no_draw_when_linewidth_zero():
    laser = DfbLaser(load_laser("dfb_default"))
    rng = np.random.default_rng(5)
    dt = 2e-9
    phi = laser.phase_noise_rad(2000, dt, rng, shape=(200,))
    assert phi.shape == (200, 2000) and phi.dtype == np.float64
    inc = np.diff(phi, axis=-1)
    assert np.var(inc) == pytest.approx(2 * np.pi * laser.linewidth_hz * dt, rel=0.02)
    # variance over a lag of 100 samples grows linearly (Wiener): 2 tau / tau_c
    lag = phi[:, 100:] - phi[:, :-100]
    assert np.var(lag) == pytest.approx(2 * 100 * dt / laser.coherence_time_s, rel=0.06)

    ideal = DfbLaser(load_laser("ideal"))
    state = rng.bit_generator.state
    assert ideal.phase_noise_rad(1000, dt, rng) is None
    assert rng.bit_generator.state == state


def test_linewidth_property_follows_coherence_time():
    p = LaserPreset(carrier_hz_per_v=1e9, thermal=[ThermalTerm(gain_hz_per_v=-3e9, tau_s=1e-6)],
                    coherence_time_s=1e-6)
    laser = DfbLaser(p)
    assert laser.linewidth_hz == pytest.approx(1 / (np.pi * 1e-6))
    assert laser.static_tuning_hz_per_v == pytest.approx(-2e9)
