"""The single-tone residual test for unresolved returns (lidard.dsp.resolve) on hard cases, through the
frame DSP: one tone at any sub-bin position and phase is never flagged; two tones a bin apart always
are, whatever their amplitude ratio and phases; half a bin apart they are unless their relative phase
at the ramp's centre is near zero (where their sum is one tone with a tapered envelope: tested to
stay between the two ranges). Beats: f = 2 gamma d / c on both ramps (static targets, eq. 2-1)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.gate import PointFlag
from lidard.dsp.rangefft import C_M_PER_S

GAMMA = 8.6e9 / 80e-6
DSP = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6,
               max_range_m=2.0, max_speed_mps=0.4)
CELL_M = DSP.range_resolution_m          # one bin of the used ramp: 19.4 mm


def _segments(ranges_m, amps, phases, noise_rms, rng):
    """(n_pix, 1, 800) real beats: up and down ramps with the same tones (static targets). The phase
    is given at the ramp's centre, where the relative phase of two returns is 2 pi nu_mid dtau."""
    n = DSP.ramp_samples
    t = (np.arange(n) - (DSP.offset + DSP.n_used / 2)) / DSP.fs_hz
    f = 2 * GAMMA * np.asarray(ranges_m)[..., None] / C_M_PER_S           # (n_pix, tones, 1)
    ramp = np.sum(np.asarray(amps)[..., None] * np.cos(2 * np.pi * f * t + np.asarray(phases)[..., None]), axis=1)
    seg = np.concatenate([ramp, ramp], axis=-1) + noise_rms * rng.standard_normal((len(ranges_m), 2 * n))
    return seg[:, None, :]


def _process(ranges_m, amps, phases, snr_db=40.0, seed=0):
    rng = np.random.default_rng(seed)
    # noise per sample for a peak-to-noise-per-bin power ratio snr_db: a real tone of amplitude A peaks
    # at A / 2 (spectrum normalised by sum w), white noise gives sigma^2 sum w^2 / (sum w)^2 = 1.5 sigma^2 / N
    noise = 0.5 * np.max(amps) * np.sqrt(DSP.n_used / 1.5) / 10 ** (snr_db / 20)
    res = DSP.process(_segments(ranges_m, amps, phases, noise, rng))
    return res


def _one_point_flags(res):
    first = res.present & (np.cumsum(res.present, axis=1) == 1)
    return res.flags[first], res.range_m[first], res.valid[res.present]


def test_one_tone_is_never_unresolved():
    rng = np.random.default_rng(1)
    d = rng.uniform(0.8, 1.8, 300)          # above the 0.4 m/s prior's ambiguity limit (~0.72 m)
    res = _process(d[:, None], np.ones((300, 1)), rng.uniform(0, 2 * np.pi, (300, 1)), snr_db=35.0, seed=2)
    flags, rng_m, valid = _one_point_flags(res)
    assert flags.size == 300
    assert not np.any(flags & PointFlag.UNRESOLVED)
    assert np.all(valid)


@pytest.mark.parametrize("ratio", [1.0, 0.5, 0.3])
def test_two_tones_a_cell_apart_are_always_flagged(ratio):
    rng = np.random.default_rng(3)
    d = rng.uniform(0.8, 1.6, 200)
    ranges = np.stack([d, d + CELL_M], axis=1)
    res = _process(ranges, np.tile([1.0, ratio], (200, 1)), rng.uniform(0, 2 * np.pi, (200, 2)), snr_db=35.0)
    assert not np.any(res.valid & res.present)                       # never a made-up valid point
    flags, _, _ = _one_point_flags(res)
    assert np.all(flags & PointFlag.UNRESOLVED)


@pytest.mark.parametrize("ratio", [1.0, 0.5])
def test_half_a_cell_apart_flagged_unless_in_phase(ratio):
    rng = np.random.default_rng(4)
    d = rng.uniform(0.8, 1.6, 200)
    ranges = np.stack([d, d + 0.5 * CELL_M], axis=1)
    rel = rng.uniform(0.5 * np.pi, 1.5 * np.pi, 200)                  # away from in phase
    ph = np.stack([np.zeros(200), rel], axis=1)
    flags, _, _ = _one_point_flags(_process(ranges, np.tile([1.0, ratio], (200, 1)), ph, snr_db=35.0))
    assert np.all(flags & PointFlag.UNRESOLVED)
    # in phase at the ramp's centre: one tone with a tapered envelope; when it passes, it is ONE
    # point between the two surfaces (never two, never outside)
    res = _process(ranges, np.tile([1.0, ratio], (200, 1)), np.zeros((200, 2)), snr_db=35.0)
    assert np.all(res.present.sum(axis=1) <= 1)
    flags, rng_m, _ = _one_point_flags(res)
    ok = (flags & PointFlag.UNRESOLVED) == 0
    assert np.all((rng_m[ok] > d[ok] - 1e-3) & (rng_m[ok] < d[ok] + 0.5 * CELL_M + 1e-3))


def test_floor_median_is_numpys_median():
    # the one-partition median of floor_noise (issue 18) against np.median, odd and even lengths
    from lidard.dsp.resolve import _median_last

    rng = np.random.default_rng(5)
    for n in (361, 360, 7, 2):
        p = rng.exponential(size=(3, 4, n))
        np.testing.assert_array_equal(_median_last(p), np.median(p, axis=-1))


def test_unresolved_tests_only_valid_slots_and_matches_the_all_slot_residual():
    # the single-tone test on the valid, judged slots alone (issue 18) decides as the residual of
    # every slot does; an empty slot is never flagged
    from lidard.dsp.resolve import (DC_BINS, HALF_BINS, MODEL_FLOOR, NOISE_FACTOR, floor_noise,
                                    single_tone_residual, unresolved)

    rng = np.random.default_rng(8)
    n, n_pix, n_avg = 256, 12, 3
    t = np.arange(n)
    f = rng.uniform(30, 90, (n_pix, 1, 1))
    x = np.cos(2 * np.pi * f * t / n) + 0.7 * np.cos(2 * np.pi * (f + 0.45) * t / n + 1.0) * (np.arange(n_pix) % 2)[:, None, None]
    x = x + rng.normal(0, 0.05, (n_pix, n_avg, n))
    w = np.hanning(n + 1)[:-1]
    spec = np.fft.rfft(x * w, axis=-1) / w.sum()
    idx = np.stack([np.argmax(np.abs(spec).mean(axis=1), axis=-1), np.full(n_pix, 5)], axis=-1)
    frac = np.stack([f[:, 0, 0], np.full(n_pix, 5.0)], axis=-1)     # the (first) tone's frequency
    valid = np.stack([np.ones(n_pix, bool), np.zeros(n_pix, bool)], axis=-1)
    got = unresolved(spec, idx, frac, valid, np.ones(idx.shape), window="hann", n_samples=n, average_axis=1)
    resid, energy = single_tone_residual(spec, idx, frac, window="hann", n_samples=n, average_axis=1)
    expected = NOISE_FACTOR * (2 * HALF_BINS + 1) * n_avg * floor_noise(spec, 1)[:, None]
    judged = (frac >= DC_BINS) & (idx - HALF_BINS >= 0)
    want = valid & judged & (resid > expected) & (resid > MODEL_FLOOR * energy)
    np.testing.assert_array_equal(got, want)
    assert not got[:, 1].any()
    assert got[1::2, 0].all() and not got[0::2, 0].any()   # the two-tone pixels, and only those


def test_two_returns_five_cells_apart_are_both_clean_points():
    # both detected, each inside the other's +-3-cell fit window (a pane 0.1 m in front of a wall):
    # fitted jointly as two known tones they are two clean points at their ranges, not "unresolved"
    rng = np.random.default_rng(8)
    d = rng.uniform(0.8, 1.4, 60)
    for sep_cells in (4.5, 5.5):
        ranges = np.stack([d, d + sep_cells * CELL_M], axis=1)
        res = _process(ranges, np.tile([1.0, 0.7], (60, 1)), rng.uniform(0, 2 * np.pi, (60, 2)), snr_db=35.0, seed=9)
        assert np.all(res.present.sum(axis=1) == 2)
        assert not np.any(res.flags[res.present] & PointFlag.UNRESOLVED), sep_cells
        got = np.sort(np.where(res.present, res.range_m, np.nan), axis=1)
        assert np.nanmax(np.abs(got - ranges)) < 2e-3


def test_two_returns_two_cells_apart_keep_the_single_tone_verdict():
    # nearer than NEIGHBOUR_MIN_BINS each one's leakage biases the other's frequency: still flagged
    rng = np.random.default_rng(10)
    d = rng.uniform(0.8, 1.4, 60)
    ranges = np.stack([d, d + 2.5 * CELL_M], axis=1)
    res = _process(ranges, np.tile([1.0, 0.7], (60, 1)), rng.uniform(0, 2 * np.pi, (60, 2)), snr_db=35.0, seed=11)
    two = res.present.sum(axis=1) == 2
    assert two.sum() > 30
    assert np.all((res.flags & PointFlag.UNRESOLVED)[two].any(axis=1))
