"""Per-thread scratch buffers (lidard.dsp.spectrum.scratch) and the DSP paths that write into them."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lidard.dsp.spectrum import rangefft
from lidard.dsp.spectrum import scratch as scratch_mod
from lidard.dsp.chain import measure_peaks
from lidard.dsp.spectrum.rangefft import RangeFFT
from lidard.dsp.spectrum.scratch import scratch
from lidard.dsp.spectrum.window import DspInputError


def test_same_tag_reuses_memory_other_tags_and_threads_do_not():
    a = scratch("t.a", (100, 8), np.float64)
    b = scratch("t.a", (50, 4), np.complex128)          # smaller: the same memory
    c = scratch("t.b", (100, 8), np.float64)
    assert np.shares_memory(a, b) and not np.shares_memory(a, c)
    assert b.shape == (50, 4) and b.dtype == np.complex128
    other = []
    th = threading.Thread(target=lambda: other.append(scratch("t.a", (100, 8), np.float64)))
    th.start()
    th.join()
    assert not np.shares_memory(a, other[0])
    big = scratch("t.a", (100, 80), np.float64)         # larger than the buffer: a new one
    assert big.nbytes == 64_000 and not np.shares_memory(big, a)
    scratch_mod.release()
    assert not np.shares_memory(scratch("t.a", (100, 8), np.float64), big)


def test_huge_requests_are_not_kept(monkeypatch):
    monkeypatch.setattr(scratch_mod, "MAX_BYTES", 1000)
    a = scratch("t.huge", (200,), np.float64)
    b = scratch("t.huge", (200,), np.float64)
    assert not np.shares_memory(a, b)


def test_spectrum_into_a_buffer_equals_the_allocated_one_and_keeps_the_scale():
    n = 256
    rf = RangeFFT(n, 1e6, 1e12, window="hann")
    rng = np.random.default_rng(0)
    k = 37.0
    x = 3.0 * np.cos(2 * np.pi * k * np.arange(n) / n + 0.4) + 0.01 * rng.standard_normal((5, n))
    out = np.empty(rf.spectrum_shape((5,)), np.complex128)
    s1 = rf(x, out=out)
    assert s1 is out
    s2 = rf(x)
    np.testing.assert_array_equal(s1, s2)
    # |X| = A/2 for a real cosine on a bin (module convention), within the noise
    assert np.allclose(np.abs(s2[:, 37]), 1.5, atol=2e-3)
    # the windowed product is a scratch buffer: a second transform leaves the first spectrum alone
    first = rf(x[:2])
    keep = first.copy()
    rf(2 * x[:2])
    np.testing.assert_array_equal(first, keep)


def test_measure_peaks_results_survive_the_next_call():
    """Its spectrum is a scratch buffer; nothing it returns may point into it."""
    n = 512
    rf = RangeFFT(n, 5e6, 1e14, window="hann")
    t = np.arange(n)
    a = np.cos(2 * np.pi * 40.3 * t / n)[None, :] + np.zeros((3, 1))
    b = np.cos(2 * np.pi * 90.7 * t / n)[None, :] + np.zeros((3, 1))
    ra = measure_peaks(rf, a, pfa=1e-6, max_detections=2)
    fa = ra.freq_hz.copy()
    measure_peaks(rf, b, pfa=1e-6, max_detections=2)
    np.testing.assert_array_equal(ra.freq_hz, fa)
    assert np.allclose(ra.freq_hz[:, 0] / rf.delta_f, 40.3, atol=1e-6)


def test_a_scans_point_buffer_releases_the_threads_buffers():
    from lidard.instrument.points import PointBuffer
    a = scratch("t.scan", (1000,), np.float64)
    pb = PointBuffer(None, None, lsb_v=1.0, mzi_delay_s=0.0, flush_bytes=1)   # nothing pending: no DSP runs
    assert pb.points().size == 0
    assert not np.shares_memory(scratch("t.scan", (1000,), np.float64), a)


@pytest.mark.parametrize("layout,iq", [("real", False), ("shifted", True), ("analytic", True)])
@pytest.mark.parametrize("zero_pad", [1, 2])
def test_chunked_windowed_fft_is_the_whole_batch_transform(layout, iq, zero_pad):
    """300 ramps of 1024 go through in several chunks and a remainder; each ramp's spectrum (and its
    power) must be exactly the one-call numpy transform of the windowed ramp."""
    n, m = 1024, 300
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, m // 3, n))
    if iq:
        x = x + 1j * rng.standard_normal(x.shape)
    w = np.hanning(n + 1)[:-1]
    n_fft = n * zero_pad
    assert m > rangefft._CHUNK_BYTES // (16 * n_fft)          # more than one chunk
    pw = np.empty(x.shape[:-1] + ((n_fft if layout == "shifted" else n_fft // 2 + 1),))
    got = rangefft.windowed_fft(x, w, n_fft, layout, power_out=pw)
    if layout == "real":
        want = np.fft.rfft(x * w, n=n_fft, axis=-1)
    elif layout == "shifted":
        want = np.fft.fftshift(np.fft.fft(x * w, n=n_fft, axis=-1), axes=-1)
    else:
        want = np.fft.fft(x * w, n=n_fft, axis=-1)[..., :n_fft // 2 + 1]
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(pw, want.real ** 2 + want.imag ** 2)


def test_windowed_fft_names_a_wrong_output_buffer():
    x = np.zeros((4, 64))
    w = np.ones(64)
    with pytest.raises(DspInputError, match="power_out must be a C-contiguous float64 array of shape"):
        rangefft.windowed_fft(x, w, 64, "real", power_out=np.empty((4, 33), np.float32))
    with pytest.raises(DspInputError, match="out must be a C-contiguous complex128"):
        rangefft.windowed_fft(x, w, 64, "real", out=np.empty((4, 40), complex)[:, :33])
    with pytest.raises(DspInputError, match="window of shape"):
        rangefft.windowed_fft(x, np.ones(32), 64, "real")


def test_frame_codes_skip_the_finite_check_and_float_volts_keep_it():
    """Integer ADC codes cannot hold NaN: the frame transforms them without the check pass, and gets the
    same frame as from the same values given as floats; a NaN in float volts is still named."""
    from lidard.dsp.frame import FrameDsp

    n, fs, gamma = 400, 5e6, 1e14
    dsp = FrameDsp(ramp_samples=n, fs_hz=fs, chirp_rate_hz_per_s=gamma, wavelength_m=1.55e-6, max_range_m=3.0,
                   min_range_m=1.0, max_speed_mps=0.4, use_fraction=0.9)
    t = np.arange(2 * n) / fs
    f_b = 2 * gamma * 2.0 / 299_792_458.0          # a target at 2 m, 1.33 MHz
    rng = np.random.default_rng(4)
    codes = np.rint(3000 * np.cos(2 * np.pi * f_b * t) + 30 * rng.standard_normal((6, 2, 2 * n))).astype(np.int16)
    a = dsp.process(codes, 1e-4)
    b = dsp.process(codes.astype(np.float64), 1e-4)
    for field in ("valid", "range_m", "velocity_mps", "snr_db", "flags"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.valid[:, 0].all() and np.allclose(a.range_m[:, 0], 2.0, atol=0.01)
    bad = codes.astype(np.float64)
    bad[2, 1, n // 2] = np.nan                    # inside the up ramp's used samples
    with pytest.raises(DspInputError, match="x contains 1 NaN and 0 infinite sample"):   # the sample, named
        dsp.process(bad, 1e-4)
