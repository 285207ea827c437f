"""Beat synthesis: frequency (eq. 2-1), Doppler (eqs. 2-4/2-5), amplitude and noise floor (eqs. 2-13,
2-14), quantization, overrange, batching."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_laser
from lidard.physics.budget import quantization_asd
from lidard.physics.constants import C_M_PER_S
from sim_devices.world import synth as synth_mod
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, MonitorMzi, SynthError, synthesize, trajectory

RAMP_S = 80e-6
EXC_HZ = 8.6e9
GAMMA = EXC_HZ / RAMP_S
WL_M = 1.55e-6


@pytest.fixture(scope="module")
def ideal_traj():
    laser = DfbLaser(load_laser("ideal"))
    fs_awg = 100e6
    return trajectory(laser, triangle_drive(EXC_HZ, RAMP_S, fs_awg, laser.static_tuning_hz_per_v), fs_awg)


def _asd(x, fs):
    """Single-sided ASD per eq. 2-13 of each row of x (rectangular window)."""
    n = x.shape[-1]
    return np.sqrt(2.0 * np.abs(np.fft.fft(x, axis=-1)) ** 2 / (n * fs))


def test_beat_frequency_is_2_gamma_d_over_c_within_one_bin(ideal_traj):
    fs = 120e6                                # Nyquist 60 MHz: 2 gamma d / c for d up to 80 m
    n = int(RAMP_S * fs)
    adc = AdcSpec(fs, n, bits=12, input_range_v=2.0, quantize=False)
    d = np.array([1.0, 3.7, 12.0, 40.0, 70.0])
    hits = HitBatch.from_targets(np.arange(d.size), d, 0.5)
    r = synthesize(ideal_traj, adc, np.arange(d.size) * ideal_traj.period_s, hits)
    spec = np.abs(np.fft.rfft(r.beat, axis=1))
    f = np.fft.rfftfreq(n, 1 / fs)
    f_peak = f[np.argmax(spec, axis=1)]
    assert np.all(np.abs(f_peak - 2 * GAMMA * d / C_M_PER_S) <= fs / n)


@pytest.mark.parametrize("v_receding", [-3.0, 2.0])
def test_doppler_up_and_down_beats_follow_eqs_2_4_and_2_5(ideal_traj, v_receding):
    fs = 40e6
    n = int(RAMP_S * fs)
    adc = AdcSpec(fs, n, bits=12, input_range_v=2.0, iq=True, quantize=False)
    d = 15.0
    hits = HitBatch.from_targets([0, 1], [d, d], 0.5, radial_velocity_m_s=v_receding, wavelength_m=WL_M)
    assert np.all(np.sign(hits.doppler_hz) == -np.sign(v_receding))     # receding -> red shift
    t0 = np.array([0.0, RAMP_S])                                        # up ramp, then down ramp
    r = synthesize(ideal_traj, adc, t0, hits)
    z = r.beat + 1j * r.beat_q
    f = np.fft.fftfreq(n, 1 / fs)
    f_peak = f[np.argmax(np.abs(np.fft.fft(z, axis=1)), axis=1)]
    V = -v_receding                                                     # approaching speed
    f_up = 2 * GAMMA * d / C_M_PER_S - 2 * V / WL_M                     # eq. 2-4
    f_down = 2 * GAMMA * d / C_M_PER_S + 2 * V / WL_M                   # eq. 2-5
    assert abs(f_peak[0] - f_up) <= fs / n
    assert abs(f_peak[1] - (-f_down)) <= fs / n                         # I/Q: down-ramp tone is negative
    # eqs. 2-6 / 2-7 recover distance and velocity
    assert (f_peak[0] - f_peak[1]) * C_M_PER_S / (4 * GAMMA) == pytest.approx(d, abs=C_M_PER_S / (2 * EXC_HZ))
    assert WL_M * (-f_peak[1] - f_peak[0]) / 4 == pytest.approx(V, abs=WL_M / (2 * RAMP_S))


def test_peak_asd_is_amplitude_sqrt_T_over_2_and_noise_floor_follows_the_asd(ideal_traj):
    fs = 20e6
    n = int(RAMP_S * fs)
    adc = AdcSpec(fs, n, bits=16, input_range_v=4.0, quantize=False)
    n_seg = 64
    j = 120                                   # integer bin: f_b T = gamma tau T = EXC tau
    tau = j / EXC_HZ
    amp = 0.3
    asd = 2e-6
    hits = HitBatch(seg=np.arange(n_seg), tau_s=np.full(n_seg, tau), amplitude_v=np.full(n_seg, amp))
    r = synthesize(ideal_traj, adc, np.arange(n_seg) * ideal_traj.period_s, hits,
                   effects=Effects(noise_asd_v_per_rthz=asd), rng=np.random.default_rng(3))
    a = _asd(r.beat, fs)
    peak = np.mean(a[:, j])
    assert peak == pytest.approx(amp * np.sqrt(RAMP_S / 2), rel=0.01)      # eq. 2-14, tau_c = inf
    floor = np.sqrt(np.mean(a[:, 200:n // 2 - 10] ** 2))
    assert floor == pytest.approx(asd, rel=0.03)


def test_noise_only_segments_and_per_segment_asd(ideal_traj):
    fs = 10e6
    n = 512
    adc = AdcSpec(fs, n, bits=16, input_range_v=4.0, quantize=False)
    asd = np.array([1e-6, 0.0, 4e-6, 0.0] * 16)
    r = synthesize(ideal_traj, adc, np.zeros(asd.size), None, effects=Effects(noise_asd_v_per_rthz=asd),
                   rng=np.random.default_rng(0))
    assert np.all(r.beat[1::2] == 0.0)                                  # no hit, no noise: silence
    std = r.beat.std(axis=1)
    assert np.mean(std[2::4]) / np.mean(std[0::4]) == pytest.approx(4.0, rel=0.05)
    assert np.mean(std[0::4]) == pytest.approx(1e-6 * np.sqrt(fs / 2), rel=0.05)


def test_quantization_noise_adds_to_the_analog_floor(ideal_traj):
    fs = 20e6
    n = int(RAMP_S * fs)
    bits, rng_v = 8, 1.0
    lsb = rng_v / 2**bits
    asd = lsb / np.sqrt(fs / 2)                 # one LSB rms of analog noise dithers the quantizer
    adc = AdcSpec(fs, n, bits=bits, input_range_v=rng_v)
    r = synthesize(ideal_traj, adc, np.zeros(32), None, effects=Effects(noise_asd_v_per_rthz=asd), rng=np.random.default_rng(1))
    assert r.beat.dtype == np.int16
    v = r.beat * r.lsb_v
    a = _asd(v, fs)
    floor = np.sqrt(np.mean(a[:, 5:n // 2 - 5] ** 2))
    expected = np.hypot(asd, quantization_asd(rng_v, bits, fs))
    assert floor == pytest.approx(expected, rel=0.04)


def test_overrange_is_flagged_and_codes_clip(ideal_traj):
    fs = 20e6
    n = 800
    adc = AdcSpec(fs, n, bits=8, input_range_v=1.0)
    hits = HitBatch.from_targets([0, 2], [5.0, 5.0], [0.8, 0.3])
    r = synthesize(ideal_traj, adc, np.zeros(3), hits)
    assert r.overrange[:, 0].tolist() == [True, False, False]
    assert r.beat[0].max() == 127 and r.beat[0].min() == -128
    assert 70 <= r.beat[2].max() <= 77                                   # 0.3 V / (1/256 V) = 76.8
    # unquantized: clipped volts, same flag
    r2 = synthesize(ideal_traj, AdcSpec(fs, n, bits=8, input_range_v=1.0, quantize=False), np.zeros(3), hits)
    assert r2.overrange[:, 0].tolist() == [True, False, False]
    assert r2.beat[0].max() == pytest.approx(0.5)


def test_several_hits_per_segment_add_up_and_chunking_does_not_matter(ideal_traj, monkeypatch):
    fs = 20e6
    n = 600
    adc = AdcSpec(fs, n, bits=12, input_range_v=4.0, quantize=False)
    seg = np.array([3, 0, 3, 3, 5, 0, 7])
    d = np.array([2.0, 4.0, 9.0, 30.0, 1.0, 11.0, 6.0])
    a = np.array([0.1, 0.2, 0.3, 0.15, 0.25, 0.05, 0.3])
    t0 = np.arange(8) * ideal_traj.period_s + 7e-6
    together = synthesize(ideal_traj, adc, t0, HitBatch.from_targets(seg, d, a)).beat
    alone = sum(synthesize(ideal_traj, adc, t0, HitBatch.from_targets(seg[i:i + 1], d[i:i + 1], a[i:i + 1])).beat
                for i in range(seg.size))
    assert np.allclose(together, alone, atol=1e-12)
    assert np.all(together[[1, 2, 4, 6]] == 0.0)
    monkeypatch.setattr(synth_mod, "_CHUNK_ELEMENTS", 2 * n)               # 2 segments per chunk
    chunked = synthesize(ideal_traj, adc, t0, HitBatch.from_targets(seg, d, a)).beat
    assert np.allclose(chunked, together, atol=1e-12)


def test_segments_are_periodic_in_the_drive_period(ideal_traj):
    fs = 20e6
    adc = AdcSpec(fs, 700, bits=12, input_range_v=4.0, quantize=False)
    hits = HitBatch.from_targets([0, 1, 2], [8.0, 8.0, 8.0], 0.4, radial_velocity_m_s=0.0)
    t0 = np.array([3e-6, 3e-6 + 1000 * ideal_traj.period_s, 3e-6 + 123457 * ideal_traj.period_s])
    r = synthesize(ideal_traj, adc, t0, hits)
    assert np.allclose(r.beat[1], r.beat[0], atol=1e-6)
    assert np.allclose(r.beat[2], r.beat[0], atol=1e-6)


def test_mzi_channel_beats_at_gamma_tau_m(ideal_traj):
    fs = 50e6
    n = int(RAMP_S * fs)
    tau_m = 40e-9
    adc = AdcSpec(fs, n, bits=12, input_range_v=2.0, quantize=False)
    r = synthesize(ideal_traj, adc, np.zeros(1), None, mzi=MonitorMzi(tau_m, 0.3))
    assert r.channels == ("beat", "mzi")
    spec = np.abs(np.fft.rfft(r.mzi[0]))
    f = np.fft.rfftfreq(n, 1 / fs)
    assert abs(f[np.argmax(spec)] - GAMMA * tau_m) <= fs / n
    assert np.max(np.abs(r.mzi)) == pytest.approx(0.3, rel=1e-3)


def test_bad_inputs_raise_named_errors(ideal_traj):
    adc = AdcSpec(10e6, 100)
    with pytest.raises(SynthError, match="HitBatch.seg"):
        synthesize(ideal_traj, adc, np.zeros(2), HitBatch.from_targets([2], [1.0], 0.1))
    with pytest.raises(SynthError, match="tau_s"):
        synthesize(ideal_traj, adc, np.zeros(2), HitBatch(seg=np.array([0]), tau_s=np.array([-1e-9]),
                                                          amplitude_v=np.array([0.1])))
    with pytest.raises(SynthError, match="mzi.amplitude_v"):
        synthesize(ideal_traj, adc, np.zeros(2), None, mzi=MonitorMzi(1e-8, float("nan")))
    with pytest.raises(SynthError, match="mzi.delay_s"):
        synthesize(ideal_traj, adc, np.zeros(2), None, mzi=MonitorMzi(0.0, 0.3))
    with pytest.raises(SynthError, match="rng"):
        synthesize(ideal_traj, adc, np.zeros(2), None, effects=Effects(noise_asd_v_per_rthz=1e-6))
    with pytest.raises(SynthError, match="noise_asd_v_per_rthz"):
        synthesize(ideal_traj, adc, np.zeros(2), None, effects=Effects(noise_asd_v_per_rthz=[1e-6, 1e-6, 1e-6]),
                   rng=np.random.default_rng(0))
    with pytest.raises(SynthError, match="bits"):
        AdcSpec(10e6, 100, bits=20)
    with pytest.raises(SynthError, match="t_start_s"):
        synthesize(ideal_traj, adc, np.array([np.nan]), None)


def test_dc_offset_and_codes_match_the_analog_volts_within_half_an_lsb(ideal_traj):
    fs = 20e6
    n = 1000
    # 8 bits over 1 V: LSB = 1/256 V; 0.1 V -> code round(25.6) = 26
    r = synthesize(ideal_traj, AdcSpec(fs, n, bits=8, input_range_v=1.0), np.zeros(2), None, effects=Effects(dc_v=0.1))
    assert np.all(r.beat == 26)
    # quantized output (fast float32 trig) vs float64-trig volts of the same hits, 12 bits
    adc = AdcSpec(fs, n, bits=12, input_range_v=1.0, iq=True)
    hits = HitBatch.from_targets([0, 1, 1], [3.0, 7.5, 22.0], [0.2, 0.15, 0.1], radial_velocity_m_s=[0.5, -2.0, 0.0])
    q = synthesize(ideal_traj, adc, np.array([0.0, 3e-5]), hits)
    v = synthesize(ideal_traj, AdcSpec(fs, n, bits=12, input_range_v=1.0, iq=True, quantize=False),
                   np.array([0.0, 3e-5]), hits)
    for codes, volts in ((q.beat, v.beat), (q.beat_q, v.beat_q)):
        # float32 trig errs by ~1e-7 x amplitude ~ 2e-4 LSB here: it may move a sample across a
        # rounding boundary, never further
        assert np.max(np.abs(codes * q.lsb_v - volts)) <= 0.501 * q.lsb_v


def test_hybrid_imbalance_puts_g_sin_of_the_phase_plus_eps_on_q(ideal_traj):
    """Q = g A sin(dPhi + eps) (lidard.dsp.ranging.iqbalance's model), I unchanged, the same hits and phase."""
    fs, n = 20e6, 1600
    adc = AdcSpec(fs, n, bits=12, input_range_v=2.0, iq=True, quantize=False)
    hits = HitBatch.from_targets([0, 1, 1], [3.0, 7.5, 22.0], [0.2, 0.15, 0.1], radial_velocity_m_s=[0.5, -2.0, 0.0])
    t0 = np.array([0.0, 3e-5])
    ideal = synthesize(ideal_traj, adc, t0, hits)
    g, eps = 1.08, 0.09
    bad = synthesize(ideal_traj, adc, t0, hits, effects=Effects(iq_imbalance=(g, eps)))
    assert np.array_equal(bad.beat, ideal.beat)
    # sin(x + eps) = sin x cos eps + cos x sin eps, summed over the hits of a segment
    assert np.allclose(bad.beat_q, g * (ideal.beat_q * np.cos(eps) + ideal.beat * np.sin(eps)), atol=1e-12)
