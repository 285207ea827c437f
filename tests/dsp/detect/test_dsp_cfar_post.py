"""The detector's post-processing on the list of detections (lidard.dsp.detect._post, issue 18) against
the dense (ramps x slots x slots) forms it replaced: the same flags and ranks, bit for bit."""

import numpy as np
import pytest

from lidard.dsp.detect import cfar


def _harmonic_dense(idx, pk, valid, *, n_bins, iq, zero_pad, harmonic_ratio_db):
    # every (ramp, strong j, weak i) triple at once: a ghost is within 1.5 zero_pad h bins of the
    # h-th harmonic (aliased about Nyquist, or into the two-sided band) of a peak stronger by the ratio
    n_fft = n_bins if iq else 2 * (n_bins - 1)
    fbin = (idx - n_fft // 2) if iq else idx
    harm = np.zeros(idx.shape, dtype=bool)
    ratio = 10 ** (harmonic_ratio_db / 10.0)
    for h in (2, 3):
        hf = h * fbin[:, :, None].astype(np.float64)
        if iq:
            alias = (hf + n_fft / 2) % n_fft - n_fft / 2
        else:
            m = np.mod(hf, n_fft)
            alias = np.minimum(m, n_fft - m)
        close = np.abs(fbin[:, None, :] - alias) <= 1.5 * zero_pad * h
        strong = pk[:, :, None] >= ratio * pk[:, None, :]
        harm |= (close & strong & valid[:, :, None] & valid[:, None, :]).any(axis=1)
    return harm


@pytest.mark.parametrize("iq", [False, True])
@pytest.mark.parametrize("zero_pad", [1, 2])
@pytest.mark.parametrize("ratio_db", [15.0, 0.0, -3.0])
def test_harmonic_ghosts_on_valid_pairs_equal_the_dense_test(iq, zero_pad, ratio_db):
    rng = np.random.default_rng(zero_pad + 3 * iq)
    rows, k = 400, 4
    n_bins = 256 if iq else 257
    n_fft = n_bins if iq else 2 * (n_bins - 1)
    valid = rng.random((rows, k)) < 0.6                 # 0 to 4 detections per ramp, gaps included
    fb = rng.integers(-n_fft // 2 if iq else 0, n_bins if not iq else n_fft // 2, (rows, k))
    # ghosts of slot 0 (weaker): at 2x (+-2 bins), at 3x, and at 2x of a high frequency (aliased)
    fb[:, 0] = rng.integers(1, n_fft // 6, rows) * (rng.choice([-1, 1], rows) if iq else 1)
    fb[::3, 1] = 2 * fb[::3, 0] + rng.integers(-2, 3, fb[::3, 0].size)
    fb[1::3, 2] = 3 * fb[1::3, 0]
    high = np.sign(fb[2::3, 0]) * (n_fft // 2 - 1 - np.abs(fb[2::3, 0]) // 2)     # 2 x high lies past Nyquist
    fb[2::3, 0] = high
    fb[2::3, 3] = (2 * high + n_fft // 2) % n_fft - n_fft // 2 if iq else n_fft - 2 * high
    idx = (fb + n_fft // 2) if iq else fb
    pk = 10 ** rng.uniform(0, 4, (rows, k))
    pk[:, 1:] = np.minimum(pk[:, 1:], pk[:, :1] * rng.uniform(1e-3, 0.2, (rows, k - 1)))
    pk[::7, 1] = pk[::7, 0]                             # equal powers: a ghost only if the ratio is <= 0 dB
    idx = np.where(valid, idx, 0)
    kw = dict(n_bins=n_bins, iq=iq, zero_pad=zero_pad, harmonic_ratio_db=ratio_db)
    got = cfar._harmonic_ghosts(idx, pk, valid, **kw)
    want = _harmonic_dense(idx, pk, valid, **kw)
    np.testing.assert_array_equal(got, want)
    assert 0 <= idx.min() and idx.max() < n_bins
    assert 30 < want.sum() < valid.sum() / 2            # the comparison covered ghosts and non-ghosts


def test_harmonic_ghosts_of_no_detections():
    valid = np.zeros((3, 2), dtype=bool)
    got = cfar._harmonic_ghosts(np.zeros((3, 2), np.int64), np.zeros((3, 2)), valid, n_bins=65, iq=False,
                                zero_pad=1, harmonic_ratio_db=15.0)
    assert got.shape == (3, 2) and not got.any()


def test_strongest_cells_rank_ramps_with_one_and_with_several_candidates():
    # most ramps hold one candidate (no sort), some several with equal powers: strongest first,
    # equal powers by the lower bin, as a full per-ramp stable sort
    rng = np.random.default_rng(5)
    p2 = rng.integers(1, 5, (300, 30)).astype(float)
    cand = np.zeros((300, 30), dtype=bool)
    cand[np.arange(300), rng.integers(0, 30, 300)] = True
    cand[::4] |= rng.random((75, 30)) < 0.3
    noise = rng.uniform(0.5, 2.0, (300, 30))
    k, idx, valid, pk, nz, snr = cfar._strongest(p2, noise, cand, 3)
    for r in range(300):
        cols = np.flatnonzero(cand[r])
        want = cols[np.argsort(-p2[r, cols], kind="stable")][:3]
        np.testing.assert_array_equal(idx[r, :want.size], want)
        np.testing.assert_array_equal(nz[r, :want.size], noise[r, want])
        np.testing.assert_array_equal(snr[r, :want.size], 10 * np.log10(p2[r, want] / noise[r, want]))
        assert valid[r].sum() == want.size


def test_strongest_cells_given_out_of_row_order_rank_as_in_row_order():
    rng = np.random.default_rng(6)
    p2 = rng.exponential(size=(50, 30))                 # distinct powers: no ties to order
    rows, cols = np.nonzero(rng.random((50, 30)) < 0.1)
    noise = rng.uniform(0.5, 2.0, rows.size)
    shuffle = rng.permutation(rows.size)
    got = cfar._strongest_cells(p2, rows[shuffle], cols[shuffle], noise[shuffle], 2)
    want = cfar._strongest_cells(p2, rows, cols, noise, 2)
    for a, b in zip(got[1:], want[1:]):
        np.testing.assert_array_equal(a, b)
    assert want[2].sum() > 50
