"""The harmonic screen at the receiver's spurious-free dynamic range (FrameDsp.sfdr_dbc, adc.sfdr_dbc;
docs/physics.md "Harmonics"): a peak at 2x a stronger one's beat is that return's harmonic only if an
unclipped receiver could have made it, i.e. if it is at least sfdr_dbc below it. Pixels drawn from
the tone model (lidard.dsp.ranging.lines), one record each, through the frame DSP."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lidard.dsp.detect.gate import PointFlag
from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.lines import lines, render

DSP = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=8.6e9 / 80e-6, wavelength_m=1.55e-6,
               max_range_m=3.2, max_speed_mps=0.4)
N_PIX = 120


def _records(ranges_m, amps, seed):
    rng = np.random.default_rng(seed)
    r = np.asarray(ranges_m, dtype=float)
    ln = lines(r, np.zeros_like(r), chirp_rate_hz_per_s=DSP.chirp_rate_hz_per_s, wavelength_m=DSP.wavelength_m)
    return render(ln, np.asarray(amps, dtype=float), rng.uniform(0, 2 * np.pi, r.shape + (3,)), fs_hz=DSP.fs_hz,
                  ramp_samples=DSP.ramp_samples, cw_samples=0), rng


def _noise(rng, shape, amp, snr_db):
    """White noise that puts a tone of amplitude ``amp`` at post-FFT SNR ``snr_db`` (N A^2 / 4 sigma^2)."""
    return amp * np.sqrt(DSP.n_used / (4 * 10 ** (snr_db / 10))) * rng.standard_normal(shape)


def _at(res, ranges_m, tol_m=5e-3):
    """Per pixel: the valid point / any point within tol of each range, and that point's flags."""
    hit = res.present[:, :, None] & (np.abs(res.range_m[:, :, None] - ranges_m[:, None, :]) < tol_m)
    valid = (hit & res.valid[:, :, None]).any(axis=1)
    flags = np.bitwise_or.reduce(np.where(hit, res.flags[:, :, None], 0), axis=1)
    return hit.any(axis=1), valid, flags


def test_a_surface_at_twice_the_range_of_a_brighter_one_is_a_point():
    # a pane at 1.0-1.5 m and a wall at exactly twice its range, 20 dB below it, nothing clipped (beats
    # above the triangle's Doppler allowance: no sign ambiguity)
    rng = np.random.default_rng(11)
    d = rng.uniform(1.0, 1.5, N_PIX)
    ranges = np.stack([d, 2 * d], axis=1)
    x, rng = _records(ranges, np.tile([1.0, 0.1], (N_PIX, 1)), seed=12)
    beat = (x + _noise(rng, x.shape, 1.0, 45.0))[:, None, :]
    seen, valid, flags = _at(DSP.process(beat), ranges)
    assert valid[:, 0].all()
    assert valid[:, 1].mean() >= 0.95, "the wall at 2x the pane's range was screened as its harmonic"
    # control: at the old screen's level (any peak 15 dB under a stronger one at 2x / 3x its beat) the
    # same wall is flagged harmonic on most pixels: the level, not the data, made the difference
    _, valid15, flags15 = _at(replace(DSP, sfdr_dbc=15.0).process(beat), ranges)
    assert valid15[:, 1].mean() < 0.1 and np.mean(flags15[:, 1] & PointFlag.HARMONIC > 0) > 0.9


def test_a_distorting_receivers_harmonic_below_its_sfdr_is_never_a_point():
    # one return at full scale through a receiver y = x + a2 x^2 whose second harmonic is 45 dBc
    # (a2 A / 2 below the tone), inside its stated 40 dBc: the harmonic at 2x the beat is detected and
    # screened, never a point; the return itself is a valid point
    rng = np.random.default_rng(21)
    d = rng.uniform(1.0, 1.5, N_PIX)
    x, rng = _records(d[:, None], np.ones((N_PIX, 1)), seed=22)
    a2 = 2 * 10 ** (-45 / 20)
    y = x + a2 * x ** 2
    beat = (y - y.mean(axis=-1, keepdims=True) + _noise(rng, x.shape, 1.0, 75.0))[:, None, :]
    res = DSP.process(beat)
    # the harmonic's range is its doubled beat's: within a few cells of 2d (its pairing is the tones')
    seen, valid, flags = _at(res, np.stack([d, 2 * d], axis=1), tol_m=3 * DSP.range_resolution_m)
    assert valid[:, 0].all()
    assert seen[:, 1].mean() >= 0.9, "the harmonic was not detected: the test would not see a missing screen"
    assert not valid[:, 1].any()
    assert np.all(flags[seen[:, 1], 1] & PointFlag.HARMONIC)
    # and for a receiver stated better than it is (60 dBc) the screen does not call it a harmonic: the
    # stated SFDR is what the screen trusts
    seen60, _, flags60 = _at(replace(DSP, sfdr_dbc=60.0).process(beat), np.stack([d, 2 * d], axis=1),
                             tol_m=3 * DSP.range_resolution_m)
    assert seen60[:, 1].mean() >= 0.9 and not np.any(flags60[:, 1] & PointFlag.HARMONIC)
