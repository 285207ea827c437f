"""CFAR side-lobe suppression (§2.4 detection; window leakage of §2.1.1): the candidate-pair form
against the dense sweep over distances, on seeded random spectra with strong tones whose side-lobes
rise above the CFAR threshold, and on random candidate sets with a hand check of a dropped cell."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.detect import cfar
from lidard.dsp.spectrum.window import WINDOW_NAMES, get_window, window_info


def _spectra(rng, rows, n, window, zero_pad):
    t = np.arange(n)
    w = get_window(window, n)
    x = rng.normal(0, 1e-3, (rows, n)) + 0j
    for _ in range(3):
        f = rng.uniform(2, n / 2 - 2, (rows, 1))
        amp = 10 ** rng.uniform(-3, 1, (rows, 1))
        x = x + amp * np.exp(2j * np.pi * f * t / n)
    spec = np.fft.fft(x * w, n * zero_pad, axis=-1)[:, : n * zero_pad // 2 + 1]
    return np.abs(spec) ** 2


@pytest.mark.parametrize("window", WINDOW_NAMES)
@pytest.mark.parametrize("zero_pad", [1, 2])
def test_pairwise_sidelobe_test_equals_the_dense_sweep(window, zero_pad, monkeypatch):
    rng = np.random.default_rng(7 + zero_pad)
    p = _spectra(rng, 40, 256, window, zero_pad)
    kw = dict(method="os", pfa=1e-4, max_detections=6, window=window, zero_pad=zero_pad)
    sparse = cfar.cfar_detect_with(p, cfar.CfarSettings(**kw))
    monkeypatch.setattr(cfar, "_SPARSE_PAIRS_PER_CELL", -1)  # force the dense sweep
    dense = cfar.cfar_detect_with(p, cfar.CfarSettings(**kw))
    for name in ("index", "power", "valid", "harmonic", "unresolved", "snr_db"):
        np.testing.assert_array_equal(getattr(sparse, name), getattr(dense, name), err_msg=name)
    assert sparse.valid.sum() >= 40  # the comparison covered real detections


@pytest.mark.parametrize("zero_pad", [1, 3])
def test_drop_sidelobes_pairs_equal_dense_on_random_candidates(zero_pad, monkeypatch):
    # the helper on its own, with many candidates of widely spread powers so that a good share
    # of them sit under a stronger one's leakage envelope
    rng = np.random.default_rng(11 + zero_pad)
    p2 = 10 ** rng.uniform(-6, 0, (60, 300))
    cand = rng.random(p2.shape) < 0.05
    info = window_info("rectangular", 64)
    env = info.leakage_envelope
    null = int(np.ceil(info.first_null_bins * zero_pad))
    max_dist = min(p2.shape[1] - 1, (env.size - 1) * zero_pad)
    margin = 10 ** 0.6
    sparse = cfar._drop_sidelobes(p2, cand, env, null, max_dist, zero_pad, margin)
    monkeypatch.setattr(cfar, "_SPARSE_PAIRS_PER_CELL", -1)
    dense = cfar._drop_sidelobes(p2, cand, env, null, max_dist, zero_pad, margin)
    np.testing.assert_array_equal(sparse, dense)
    assert not np.any(sparse & ~cand)
    dropped = (cand & ~sparse).sum()
    assert 0.05 * cand.sum() < dropped < 0.95 * cand.sum()
    # spot-check one dropped cell by hand: some other candidate beyond the null leaks over it
    r, k = np.argwhere(cand & ~sparse)[0]
    others = np.flatnonzero(cand[r])
    d = np.abs(others - k)
    ok = (d > null) & (d <= max_dist)
    assert np.any(p2[r, others[ok]] * env[d[ok] // zero_pad] * margin >= p2[r, k])


@pytest.mark.parametrize("shape", [(3, 40), (2, 5, 33), (130, 50)])
@pytest.mark.parametrize("tones", [False, True])
def test_os_noise_is_the_per_cell_sort_wherever_the_threshold_can_pass(shape, tones):
    # k-th smallest of the n_ref reference cells (guard cells skipped, mirrored at the edges); the
    # detector computes it exactly wherever a cell may pass the threshold and a lower bound elsewhere
    # (issue 18), so its decisions are those of the exact statistic everywhere
    rng = np.random.default_rng(sum(shape))
    p = rng.exponential(1.0, shape)
    if tones:   # strong cells (targets) in every row
        p.reshape(-1, shape[-1])[:, ::7] *= 300.0
    n_side, guard, k = 4, 2, 6
    noise, alpha = cfar._noise_os(p, n_side, guard, 1e-4, k)
    exact = cfar._noise_os(p, n_side, guard, 1e-4, k, exact=True)[0].reshape(-1, shape[-1])
    n = shape[-1]
    mean_kth = np.sum(1.0 / np.arange(2 * n_side - k + 1, 2 * n_side + 1))
    flat, got = p.reshape(-1, n), noise.reshape(-1, n)
    exact_cells = 0
    for r in range(flat.shape[0]):
        for i in range(n):
            offs = [o for o in range(-guard - n_side, guard + n_side + 1) if abs(o) > guard]
            j = [i + o for o in offs]
            j = [-x if x < 0 else (2 * (n - 1) - x if x >= n else x) for x in j]  # reflect
            want = np.sort(flat[r, j])[k - 1] / mean_kth
            assert got[r, i] <= want * (1 + 1e-15)                       # never above the exact
            assert exact[r, i] == pytest.approx(want, rel=1e-15)          # exact=True: every cell
            # a cell under alpha x its bound is under alpha x the exact: the same decision; one that
            # may pass was computed exactly
            if flat[r, i] > alpha[i] * got[r, i]:
                assert got[r, i] == pytest.approx(want, rel=1e-15)
                exact_cells += 1
    if tones:
        assert exact_cells > 0


@pytest.mark.parametrize("zero_pad", [1, 2])
@pytest.mark.parametrize("distance", [40.0, 60.3, 62.0, 63.6, 64.0])
def test_a_weaker_surface_far_from_a_strong_one_is_not_its_side_lobe(distance, zero_pad):
    # A Hann side-lobe 40-64 bins out is below -75 dB: a tone 20 dB under a strong one there is a
    # surface. The side-lobe screen's leakage envelope must be the ramp's window's, not a 64-sample
    # stand-in's, whose DTFT comes back to its main lobe at 64 bins (the old envelope hid these).
    n, rows = 360, 40
    rng = np.random.default_rng(int(distance * 10) + zero_pad)
    t = np.arange(n)
    f0 = 30.0 + rng.uniform(0, 1, (rows, 1))
    x = (np.cos(2 * np.pi * f0 * t / n) + 0.1 * np.cos(2 * np.pi * (f0 + distance) * t / n + 1.0)
         + 10 ** (-45 / 20) * np.sqrt(n / 4) * rng.standard_normal((rows, n)))    # near at ~45 dB post-FFT
    spec = np.fft.rfft(x * get_window("hann", n), n * zero_pad, axis=-1)
    det = cfar.cfar_detect_with(np.abs(spec) ** 2, cfar.CfarSettings(window="hann", zero_pad=zero_pad,
                                                                     pfa=1e-6, max_detections=4))
    found = det.valid & (np.abs(det.index / zero_pad - (f0 + distance)) <= 1.0)
    assert found.any(axis=1).all()
    # and the screen still works where it should: no detection on the strong tone's near side-lobes
    near = det.valid & (np.abs(det.index / zero_pad - f0) > 1.5) & (np.abs(det.index / zero_pad - f0) < 8)
    assert not near.any()
