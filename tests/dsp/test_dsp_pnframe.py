"""Batched phase-noise compensation in the frame DSP (lidard.dsp.pnframe; dissertation §2.3, Fig. 2-7).

Signals: one Wiener phase per ramp shared by the LiDAR beat and the monitor MZI (linear chirp, the
shipped 200 ns monitor delay, integer-sample delays), built here from the definitions, not by the
code under test.
"""

import math

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.phasenoise.compensate import compensated_spectrum
from lidard.dsp.pnframe import (PhaseNoiseCompensator, mzi_phase_noise_batch, process_compensated)
from lidard.dsp.spectrum.window import DspInputError

C = 299_792_458.0
FS = 250e6
GAMMA = 8.6e9 / 80e-6
TAU_M = 200e-9
RAMP_N = 5000                 # 20 us ramps
WAVELENGTH = 1.55e-6


def _ramps(shape, tau_s, linewidth_hz, rng, noise_v, amp=1.0, n=RAMP_N):
    """Beat and MZI of independent ramps (shape + (n,)); up and down ramps alike give |f_b|."""
    d, dm = int(round(tau_s * FS)), int(round(TAU_M * FS))
    pre = max(d, dm) + 4
    t = np.arange(-pre, n) / FS
    ph = np.broadcast_to(np.pi * GAMMA * t**2, tuple(shape) + (n + pre,)).copy()
    if linewidth_hz > 0:
        ph += np.cumsum(rng.standard_normal(ph.shape) * math.sqrt(2 * np.pi * linewidth_hz / FS), axis=-1)
    beat = amp * np.cos(ph[..., pre:] - ph[..., pre - d:pre - d + n] + 0.4)
    beat += noise_v * rng.standard_normal(beat.shape)
    mzi = 0.3 * np.cos(ph[..., pre:] - ph[..., pre - dm:pre - dm + n] + 1.1)
    return beat, mzi


def _segments(n_pix, n_avg, tau_s, linewidth_hz, seed, noise_v):
    rng = np.random.default_rng(seed)
    beat, mzi = _ramps((n_pix, n_avg, 2), tau_s, linewidth_hz, rng, noise_v)
    return beat.reshape(n_pix, n_avg, 2 * RAMP_N), mzi.reshape(n_pix, n_avg, 2 * RAMP_N)


def _dsp(max_range_m):
    return FrameDsp(ramp_samples=RAMP_N, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=WAVELENGTH,
                    max_range_m=max_range_m, min_range_m=1.0, max_speed_mps=0.4, use_fraction=0.7)


def test_batched_mzi_phase_equals_the_single_record_estimate():
    from lidard.dsp.phasenoise.compensate import mzi_phase_noise
    rng = np.random.default_rng(3)
    _, mzi = _ramps((3,), 0.6e-6, 1 / (math.pi * 0.1e-6), rng, 0.0)
    delta, valid = mzi_phase_noise_batch(mzi, fs_hz=FS, edge_s=1e-6, beat_hz=GAMMA * TAU_M)
    for i in range(3):
        one = mzi_phase_noise(mzi[i], fs_hz=FS, edge_s=1e-6, beat_hz=GAMMA * TAU_M)
        assert np.array_equal(one.valid, valid)
        np.testing.assert_allclose(delta[i], one.delta_rad, rtol=0, atol=1e-9)


def test_composite_spectrum_equals_single_record_compensated_spectrum():
    rng = np.random.default_rng(5)
    beat, mzi = _ramps((4,), 0.8e-6, 1 / (math.pi * 0.1e-6), rng, 0.5)
    max_delay = 1.1e-6
    comp = PhaseNoiseCompensator(fs_hz=FS, mzi_delay_s=TAU_M, max_delay_s=max_delay, chirp_rate_hz_per_s=GAMMA)
    from scipy.signal import get_window
    for i in range(4):
        cs = compensated_spectrum(beat[i], mzi[i], fs_hz=FS, mzi_delay_s=TAU_M, max_delay_s=max_delay,
                                  chirp_rate_hz_per_s=GAMMA)
        n = RAMP_N - comp.edge_samples - cs.start
        assert cs.start == comp.min_start
        w = get_window("hann", n, fftbins=False)
        ramps = comp.prepare(beat, mzi, cs.start, n)
        spec, m_of_bin = ramps.composite_spectrum(w)
        k = cs.comp.size
        got = np.abs(spec[i, :k]) * 2 * w.sum()
        np.testing.assert_allclose(got, cs.comp, rtol=0, atol=1e-9 * cs.comp.max())
        assert np.array_equal(m_of_bin[:k], cs.m_of_bin)


def _cell_hits(res, dsp, truth_m):
    """Per pixel: a valid point within one resolution cell (c / 2B over the used window) of truth."""
    near = res.present & res.valid & (np.abs(res.range_m - truth_m) <= dsp.range_resolution_m)
    return near.any(axis=1)


def test_far_target_missed_plain_is_found_with_compensation():
    tau = 5 * TAU_M                                   # 149.9 m, M = 5; tau_c = 0.1 us: tau / tau_c = 10
    truth = C * tau / 2
    dsp = _dsp(160.0)
    beat, mzi = _segments(8, 2, tau, 1 / (math.pi * 0.1e-6), seed=11, noise_v=2.0)
    plain = dsp.process(beat)
    comp, info = process_compensated(dsp, beat, mzi, mzi_delay_s=TAU_M)
    hits_plain = _cell_hits(plain, dsp, truth)
    hits_comp = _cell_hits(comp, dsp, truth)
    assert hits_plain.sum() <= 2, hits_plain
    assert hits_comp.sum() >= 7, hits_comp
    # the gate runs from M = 0 (near) to the nearest M of 160 m (5.3 tau_m)
    assert info.m_min_used == 0 and info.m_max_used == 5 and info.m_max >= 5


def test_zero_linewidth_compensation_moves_range_by_less_than_a_tenth_of_a_bin():
    for tau in (3 * TAU_M, 2.6 * TAU_M):              # on an M and between two
        dsp = _dsp(120.0)
        beat, mzi = _segments(4, 1, tau, 0.0, seed=2, noise_v=0.05)
        plain = dsp.process(beat)
        comp, _ = process_compensated(dsp, beat, mzi, mzi_delay_s=TAU_M)
        assert plain.valid[:, 0].all() and comp.valid[:, 0].all()
        bin_m = C * FS / (2 * GAMMA * dsp.n_used)
        assert np.max(np.abs(comp.range_m[:, 0] - plain.range_m[:, 0])) < 0.1 * bin_m
        assert np.max(np.abs(comp.range_m[:, 0] - C * tau / 2)) < 0.1 * bin_m


def test_bad_inputs_name_what_is_wrong():
    dsp = _dsp(160.0)
    beat, mzi = _segments(1, 1, 2 * TAU_M, 0.0, seed=1, noise_v=0.0)
    with pytest.raises(DspInputError, match="mzi must have"):
        process_compensated(dsp, beat, mzi[..., :-2], mzi_delay_s=TAU_M)
    bad = mzi.copy()
    bad[0, 0, 10] = np.nan
    with pytest.raises(DspInputError, match="NaN"):
        process_compensated(dsp, beat, bad, mzi_delay_s=TAU_M)
    short = FrameDsp(ramp_samples=RAMP_N, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=WAVELENGTH,
                     max_range_m=160.0, use_fraction=0.95)
    with pytest.raises(DspInputError, match="start >="):
        process_compensated(short, beat, mzi, mzi_delay_s=TAU_M)


def test_frame_dsp_takes_the_mzi_and_needs_its_delay():
    dsp = _dsp(160.0)
    beat, mzi = _segments(2, 1, 4 * TAU_M, 1 / (math.pi * 0.1e-6), seed=4, noise_v=0.5)
    with pytest.raises(ValueError, match="mzi_delay_s"):
        dsp.process(beat, mzi=mzi)
    res = dsp.process(beat, mzi=mzi, mzi_delay_s=TAU_M)
    assert res.valid[:, 0].all()
    assert np.all(np.abs(res.range_m[:, 0] - C * 4 * TAU_M / 2) <= dsp.range_resolution_m)


def _iq_segments(n_pix, n_avg, tau_s, linewidth_hz, seed, noise_v):
    """An I/Q receiver's complex beat (I + jQ, ideal hybrid) and the real monitor MZI: up ramp +gamma,
    down ramp -gamma (the complex beat's tone is then +gamma tau and -gamma tau), one Wiener phase per
    ramp shared by the beat and the MZI."""
    rng = np.random.default_rng(seed)
    d, dm = int(round(tau_s * FS)), int(round(TAU_M * FS))
    pre = max(d, dm) + 4
    t = np.arange(-pre, RAMP_N) / FS
    shape = (n_pix, n_avg, 2)
    ph = np.broadcast_to(np.pi * GAMMA * t ** 2, shape + (RAMP_N + pre,)).copy()
    ph[..., 1, :] *= -1.0
    if linewidth_hz > 0:
        ph += np.cumsum(rng.standard_normal(ph.shape) * math.sqrt(2 * np.pi * linewidth_hz / FS), axis=-1)
    dphi = ph[..., pre:] - ph[..., pre - d:pre - d + RAMP_N] + 0.4
    beat = np.exp(1j * dphi) + noise_v * (rng.standard_normal(dphi.shape) + 1j * rng.standard_normal(dphi.shape))
    mzi = 0.3 * np.cos(ph[..., pre:] - ph[..., pre - dm:pre - dm + RAMP_N] + 1.1)
    return beat.reshape(n_pix, n_avg, 2 * RAMP_N), mzi.reshape(n_pix, n_avg, 2 * RAMP_N)


def test_iq_far_target_missed_plain_is_found_with_compensation():
    """The I/Q receiver's complex beat is compensated as it is (no Hilbert transform), the conjugated
    down ramp with the opposite sign of the phase noise: the same gain as the real beat's."""
    tau = 5 * TAU_M
    truth = C * tau / 2
    dsp = FrameDsp(ramp_samples=RAMP_N, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=WAVELENGTH,
                   max_range_m=160.0, min_range_m=1.0, max_speed_mps=0.4, use_fraction=0.7, iq=True)
    beat, mzi = _iq_segments(8, 2, tau, 1 / (math.pi * 0.1e-6), seed=11, noise_v=1.4)
    plain = dsp.process(beat.real, beat_q=beat.imag)
    comp = dsp.process(beat.real, beat_q=beat.imag, mzi=mzi, mzi_delay_s=TAU_M)
    hits_plain, hits_comp = _cell_hits(plain, dsp, truth), _cell_hits(comp, dsp, truth)
    assert hits_plain.sum() <= 2, hits_plain
    assert hits_comp.sum() >= 7, hits_comp
    # and a zero-linewidth beat is not moved by it (on an M and between two)
    for tau0 in (3 * TAU_M, 2.6 * TAU_M):
        b, m = _iq_segments(4, 1, tau0, 0.0, seed=2, noise_v=0.05)
        p = dsp.process(b.real, beat_q=b.imag)
        c = dsp.process(b.real, beat_q=b.imag, mzi=m, mzi_delay_s=TAU_M)
        assert p.valid[:, 0].all() and c.valid[:, 0].all()
        bin_m = C * FS / (2 * GAMMA * dsp.n_used)
        assert np.max(np.abs(c.range_m[:, 0] - C * tau0 / 2)) < 0.1 * bin_m
        assert np.max(np.abs(c.velocity_mps[:, 0])) < 0.01
