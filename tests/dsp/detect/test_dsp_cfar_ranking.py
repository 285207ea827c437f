"""OS-CFAR's ranking of candidates and its mirrored padding (issue 18 rewrites) against plain references."""

import numpy as np
import pytest

from lidard.dsp.detect import cfar


def test_strongest_ranks_candidates_per_ramp_like_a_full_sort():
    rng = np.random.default_rng(11)
    p2 = rng.exponential(size=(50, 40))
    cand = rng.random((50, 40)) < 0.08            # 0 to several candidates per ramp
    noise = rng.uniform(0.5, 2.0, (50, 40))
    k, idx, valid, pk, nz, snr = cfar._strongest(p2, noise, cand, 3)
    assert k == 3
    for r in range(50):
        cols = np.flatnonzero(cand[r])
        want = cols[np.argsort(-p2[r, cols], kind="stable")][:3]
        assert valid[r].sum() == want.size
        np.testing.assert_array_equal(idx[r, :want.size], want)
        np.testing.assert_array_equal(pk[r, :want.size], p2[r, want])
        np.testing.assert_array_equal(nz[r, :want.size], noise[r, want])
        assert np.all(pk[r, want.size:] == 0) and np.all(np.isneginf(snr[r, want.size:]))


def test_strongest_breaks_equal_powers_by_the_lower_bin():
    p2 = np.array([[1.0, 5.0, 2.0, 5.0, 0.5]])
    cand = np.array([[False, True, True, True, False]])
    _, idx, valid, *_ = cfar._strongest(p2, np.ones_like(p2), cand, 2)
    np.testing.assert_array_equal(idx[0], [1, 3])
    assert valid.all()


def test_mirrored_padding_is_numpys_reflect_then_zeros():
    p = np.random.default_rng(2).random((3, 25))
    for reach in (1, 5, 10, 24):
        pp = cfar._mirror_padded(p, reach, reach + 7)
        np.testing.assert_array_equal(pp[:, :25 + 2 * reach], np.pad(p, [(0, 0), (reach, reach)], mode="reflect"))
        assert not pp[:, 25 + 2 * reach:].any()


def test_os_noise_is_exact_wherever_the_threshold_can_pass():
    # against the exact statistic at every bin (exact=True): same where a detection could be
    rng = np.random.default_rng(4)
    p = rng.exponential(size=(20, 200))
    p[:, 60] = 400.0                                # a target in each ramp
    fast, alpha = cfar._noise_os(p, 8, 2, 1e-4, None)
    full, _ = cfar._noise_os(p, 8, 2, 1e-4, None, exact=True)
    passing = p > alpha * full
    assert passing[:, 60].all()
    np.testing.assert_array_equal(fast[passing], full[passing])
    assert np.all(fast <= full)                     # elsewhere a lower bound


def test_an_empty_batch_gives_empty_detections():
    # a raw capture's last committed chunk can hold no pixel (a daemon killed between its writes): the
    # detector answers empty arrays of the batch's shape, as the frame DSP did before the ranking
    from lidard.dsp.detect.cfar import CfarSettings, cfar_detect_with
    det = cfar_detect_with(np.zeros((0, 3, 257)), CfarSettings(window="hann", max_detections=2))
    assert det.index.shape == (0, 3, 2) and not det.valid.any()


@pytest.mark.parametrize("cw_samples", [0, 3120])
def test_the_frame_dsp_answers_no_points_for_no_pixels(cw_samples):
    from lidard.dsp.frame import FrameDsp
    d = FrameDsp(ramp_samples=800, fs_hz=5e6, chirp_rate_hz_per_s=1.075e14, wavelength_m=1.55e-6, max_range_m=2.0,
                 cw_samples=cw_samples)
    res = d.process(np.zeros((0, 2, 1600 + cw_samples), np.int16))
    assert res.present.shape == (0, d.max_returns) and res.flags.dtype == np.uint8
