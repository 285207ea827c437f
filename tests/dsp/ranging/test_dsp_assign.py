"""The hypothesis scorer (lidard.dsp.ranging.assign): the assignment is the maximum-likelihood one (against
brute force), the likelihood of one amplitude on both ramps tells a return's partner from another's, and a
target faster than the digitizer's band is flagged, never a valid point (pixels drawn from the tone model)."""

from __future__ import annotations

from itertools import permutations

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.detect.gate import PointFlag
from lidard.dsp.ranging.assign import best_matching, pair_loglik, tie_llr
from lidard.dsp.ranging.lines import lines, render

GAMMA = 8.6e9 / 80e-6
WL = 1.55e-6


def _brute(score: np.ndarray) -> float:
    """The largest total over every partial one-to-one map, by enumeration of the down slots' orders."""
    ku, kd = score.shape
    best = 0.0
    cols = list(range(kd)) + [-1] * ku
    for perm in set(permutations(cols, ku)):
        tot = sum(score[i, j] for i, j in enumerate(perm) if j >= 0)
        best = max(best, tot)
    return best


@pytest.mark.parametrize("k", [2, 3, 4])
def test_the_assignment_has_the_largest_total_likelihood(k):
    rng = np.random.default_rng(k)
    n = 300
    score = rng.exponential(10.0, (n, k, k))
    score[rng.random((n, k, k)) < 0.3] = -np.inf          # pairs that are no hypothesis
    m = best_matching(score, np.zeros_like(score), tie=0.0)
    for r in range(n):
        used = m[r][m[r] >= 0]
        assert len(set(used.tolist())) == used.size                 # each down peak at most once
        got = sum(score[r, i, j] for i, j in enumerate(m[r]) if j >= 0)
        assert np.isfinite(got) and got == pytest.approx(_brute(np.where(np.isfinite(score[r]), score[r], -1e300)))


def test_a_return_pairs_with_its_own_partner_not_the_likelier_looking_crossed_one():
    # two returns, 20 and 30 dB per cell: the straight pairs (one amplitude per return) beat the crossed
    # ones by (a1 - a2)^2 L; greedy "smallest Doppler first" would take whichever pair is closest
    x_up = np.array([[100.0, 1000.0]])
    x_dn = np.array([[1000.0, 100.0]])
    ll = pair_loglik(x_up, x_dn, records=1)
    assert ll[0, 0, 1] + ll[0, 1, 0] - (ll[0, 0, 0] + ll[0, 1, 1]) == pytest.approx((1000 ** 0.5 - 100 ** 0.5) ** 2)
    motion = np.array([[[1.0, 5.0], [5.0, 1.0]]])              # the crossed pairs need less motion
    assert best_matching(ll, motion, tie_llr(1e-3)).tolist() == [[1, 0]]
    # equal amplitudes: the data cannot tell, the least motion decides
    ll = pair_loglik(np.array([[500.0, 500.0]]), np.array([[500.0, 500.0]]), records=1)
    assert best_matching(ll, motion, tie_llr(1e-3)).tolist() == [[0, 1]]


BAND = 0.4
DSP = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=WL, max_range_m=2.0,
               max_speed_mps=BAND, cw_samples=390)


def _pixels(range_m, v_mps, n=40, snr_db=35.0, seed=0):
    rng = np.random.default_rng(seed)
    r = np.full((n, 1), range_m)
    ln = lines(r, np.full_like(r, v_mps), chirp_rate_hz_per_s=GAMMA, wavelength_m=WL)
    x = render(ln, np.ones_like(r), rng.uniform(0, 2 * np.pi, (n, 1, 3)), fs_hz=DSP.fs_hz,
               ramp_samples=DSP.ramp_samples, cw_samples=DSP.cw_samples)
    sigma = np.sqrt(DSP.n_used / (4 * 10 ** (snr_db / 10)))
    return DSP.process((x + sigma * rng.standard_normal(x.shape))[:, None, :])


@pytest.mark.parametrize("range_m, v_mps", [(0.15, 3 * BAND), (0.15, -3 * BAND), (1.0, 3 * BAND),
                                            (1.5, -5 * BAND)])
def test_a_target_faster_than_the_band_is_flagged_never_valid(range_m, v_mps):
    res = _pixels(range_m, v_mps)
    assert not np.any(res.valid & res.present)
    drawn = res.present
    if range_m < 0.2:
        # both ramp beats (f_R + |f_D| <= 1.66 MHz) still lie in the searched band: drawn, flagged, and
        # drawn where the target is
        assert drawn[:, 0].all()
        assert np.abs(res.range_m[drawn] - range_m).max() < 3e-3
    # farther, the down beat lies beyond the band searched: no point at all
    assert np.all(res.flags[drawn] & PointFlag.OUT_OF_BAND)
    assert np.all(np.abs(res.velocity_mps[drawn]) > BAND)


def test_a_target_inside_the_band_is_valid_and_unflagged():
    res = _pixels(1.0, 0.7 * BAND)
    first = res.present[:, 0]
    assert first.all() and res.valid[:, 0].all()
    assert np.all((res.flags[:, 0] & PointFlag.OUT_OF_BAND) == 0)
    assert np.abs(res.range_m[:, 0] - 1.0).max() < 1e-3
    assert np.abs(res.velocity_mps[:, 0] - 0.7 * BAND).max() < 0.02
