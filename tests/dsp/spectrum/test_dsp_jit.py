"""The optional compiled kernels (lidard.dsp.spectrum.jit, issue 18) give the numpy path's results bit for bit."""

import numpy as np
import pytest

from lidard.dsp.detect import cfar
from lidard.dsp.spectrum import jit
from lidard.dsp.chain import measure_peaks
from lidard.dsp.spectrum.rangefft import RangeFFT
from tests.helpers.jit_ab import compiled_and_numpy

pytestmark = pytest.mark.skipif(jit._compiled() is None, reason="numba is not installed")



def test_power_is_re2_plus_im2():
    z = np.random.default_rng(1).standard_normal((7, 33)) * (1 + 1j) + 1j * np.arange(33)
    np.testing.assert_array_equal(jit.power(z), z.real ** 2 + z.imag ** 2)


@pytest.mark.parametrize("n_side, guard, rank", [(8, 2, None), (4, 1, 6), (3, 0, 1)])
def test_os_screen_detects_what_the_numpy_screen_does(monkeypatch, n_side, guard, rank):
    # noise with targets, edges, plateaus (equal neighbours) and all-zero rows
    rng = np.random.default_rng(n_side)
    p = rng.exponential(size=(300, 70))
    p[::3, rng.integers(0, 70, 100)] *= 500.0
    p[:, :2] *= 300.0                                   # maxima at the first cells (mirrored windows)
    p[5, 30:33] = 1e4                                   # a plateau: only its first cell is a local maximum
    p[7] = 0.0
    got, want = compiled_and_numpy(monkeypatch, lambda: cfar._os_screened(p, n_side, guard, 1e-3, rank))
    assert got[3] == want[3]                            # the same scaled alpha
    # the screens differ (per cell here, per block there); the cells that pass the exact test agree
    passing = []
    for r, c, noise, scaled_alpha in (got, want):
        ok = (p[r, c] > scaled_alpha * noise) & (noise > 0)
        passing.append((r[ok], c[ok], noise[ok]))
    for a, b in zip(*passing):
        np.testing.assert_array_equal(a, b)
    assert passing[0][0].size > 100


def test_the_chain_is_the_same_with_and_without_the_kernels(monkeypatch):
    rng = np.random.default_rng(3)
    n = 256
    t = np.arange(n)
    x = np.cos(2 * np.pi * rng.uniform(10, 118, (400, 1)) * t / n) + 0.3 * rng.standard_normal((400, n))
    rf = RangeFFT(n, 5e6, 1.075e14, window="hann")
    got, want = compiled_and_numpy(monkeypatch, lambda: measure_peaks(rf, x, pfa=1e-6, max_detections=2))
    assert want.detections.valid[:, 0].mean() > 0.9
    np.testing.assert_array_equal(got.freq_hz, want.freq_hz)
    for f in ("index", "power", "noise", "snr_db", "valid", "width_bins"):
        np.testing.assert_array_equal(getattr(got.detections, f), getattr(want.detections, f))


def test_a_full_output_buffer_is_grown(monkeypatch):
    # more passing cells than the first buffer holds: the kernel says so and runs again with more room
    p = np.zeros((2, 4000))
    p[:, 1::3] = 1e3                       # a local maximum every third cell, each far above its neighbours
    p[:, ::3] = 1.0
    p[:, 2::3] = 1.0
    r, c, noise = jit.os_screen(p, 4, 1, 6, 1.0 / 20.0, 1.0, jit.kernels())
    # each row: every peak but those whose mirrored window reaches the peak itself (at the edges)
    assert 2 * (len(range(1, 4000, 3)) - 2) <= r.size <= 2 * len(range(1, 4000, 3))
    assert np.all(c % 3 == 1) and set(range(13, 3985, 3)) <= set(c[r == 1].tolist())
    np.testing.assert_array_equal(noise, 1.0)            # the 6th smallest of 8 reference cells (two peaks)


_FIELDS = ("index", "power", "noise", "snr_db", "valid", "harmonic", "unresolved", "width_bins")


@pytest.mark.parametrize("kw", [
    dict(pfa=1e-6, max_detections=2, bin_range=(0, 128)),             # the frame's settings (rfft layout)
    dict(pfa=1e-3, max_detections=5, n_ref=8, n_guard=1, os_rank=5, window="rectangular"),
    dict(pfa=1e-4, max_detections=3, iq=True, bin_range=(140, 255)),
    dict(pfa=1e-4, max_detections=4, zero_pad=2, dc_guard_bins=0, harmonic_ratio_db=0.0),
])
def test_the_detector_is_the_same_with_and_without_the_kernels(monkeypatch, kw):
    # two tones (one clipped: harmonic ghosts), close pairs (unresolved), a ramp of zeros, a ramp
    # full of peaks: every output of cfar_detect_with bit for bit
    rng = np.random.default_rng(len(kw))
    n, rows = 256, 300
    t = np.arange(n)
    f = rng.uniform(3, 60, (rows, 1))
    x = 2 * np.cos(2 * np.pi * f * t / n) + np.cos(2 * np.pi * (f + rng.uniform(0.8, 40, (rows, 1))) * t / n)
    x = np.clip(x, -1.5, 2.5) + 0.05 * rng.standard_normal((rows, n))
    if kw.get("iq"):
        x = x * np.exp(2j * np.pi * rng.uniform(-0.3, 0.3, (rows, 1)) * t)
    w = np.hanning(n) if kw.get("window", "hann") == "hann" else np.ones(n)
    spec = np.fft.fft(x * w, n * kw.get("zero_pad", 1), axis=-1)
    spec = np.fft.fftshift(spec, axes=-1) if kw.get("iq") else spec[:, :spec.shape[-1] // 2 + 1]
    p = np.abs(spec) ** 2
    p[0] = 0.0
    p[1, ::2] = 1e3
    got, want = compiled_and_numpy(monkeypatch, lambda: cfar.cfar_detect_with(p, cfar.CfarSettings(**kw)))
    for name in _FIELDS:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert want.valid.sum() > rows and want.harmonic.any() and want.unresolved.any()


@pytest.mark.parametrize("max_half", [0, 1, 9])
def test_widths_are_the_same_with_and_without_the_kernels(monkeypatch, max_half):
    # lobes, plateaus (a crossing after equal cells: no interpolation), zero peaks, peaks at the edges
    rng = np.random.default_rng(max_half)
    p = rng.exponential(size=(200, 40))
    p[::4, 10:14] = [[20.0, 80.0, 80.0, 10.0]]
    p[1::4] = 0.0
    cols = rng.integers(0, 40, 400)
    cols[:20] = 0
    cols[20:40] = 39
    rows = np.repeat(np.arange(200), 2)
    got, want = compiled_and_numpy(monkeypatch, lambda: cfar._width_6db(p, None, max_half, rows=rows, cols=cols))
    np.testing.assert_array_equal(got, want)
    assert np.unique(want).size > 50 if max_half else not want.any()     # max_half 0: no bin looked at


@pytest.mark.parametrize("n, zero_pad", [(512, 1), (64, 2), (1000, 1)])
def test_newton_on_real_ramps_is_the_same_with_and_without_the_kernels(monkeypatch, n, zero_pad):
    """The compiled Newton step (jit_kernels.newton_real_step) and the compiled moment tables
    (jit_kernels.bin_table) against the numpy path: tones at every sub-bin offset, low and high SNR
    (Newton's uphill branch), all-zero ramps (the zero-denominator guards), peaks at DC and Nyquist
    (the one-column fit) and two peaks per ramp."""
    from lidard.dsp.ranging.estimators import estimate

    rng = np.random.default_rng(n)
    m = 600
    t = np.arange(n)
    f = rng.uniform(0, n / 2, (m, 1))
    sigma = rng.uniform(0.01, 1.0, (m, 1))
    x = np.cos(2 * np.pi * f * t / n + rng.uniform(0, 6.3, (m, 1))) + sigma * rng.standard_normal((m, n))
    x[:5] = 0.0
    pb = np.stack([np.rint(f[:, 0] * zero_pad), rng.integers(-n * zero_pad // 2 + 1, n * zero_pad // 2, m)], -1)
    pb = pb.astype(np.int64)
    pb[5:10, 0], pb[10:15, 0] = 0, n * zero_pad // 2
    got, want = compiled_and_numpy(monkeypatch, lambda: estimate(x, pb, "newton", zero_pad=zero_pad))
    assert jit.kernels() is not None
    np.testing.assert_array_equal(got, want)
    # and it is the estimator: near the truth where the tone is clear of DC, Nyquist and the noise
    clear = (sigma[:, 0] < 0.2) & (f[:, 0] > 2) & (f[:, 0] < n / 2 - 2)
    clear[:20] = False
    assert np.all(np.abs(want[clear, 0] / zero_pad - f[clear, 0]) < 0.05)


@pytest.mark.parametrize("kind", ["real", "complex"])
def test_moment_tables_are_the_same_with_and_without_the_kernels(monkeypatch, kind):
    from lidard.dsp.spectrum.dtft import _moment_basis, _moments_on_bins

    rng = np.random.default_rng(7)
    n = 300
    x = rng.standard_normal((50, n))
    if kind == "complex":
        x = x + 1j * rng.standard_normal((50, n))
    rows, f0 = rng.integers(0, 50, 200), rng.integers(-n // 2, n // 2, 200).astype(float)
    basis, _ = _moment_basis(n, 26)
    got, want = compiled_and_numpy(monkeypatch, lambda: _moments_on_bins(x, rows, f0, basis))
    np.testing.assert_array_equal(got, want)
