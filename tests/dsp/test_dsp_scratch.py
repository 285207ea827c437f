"""Per-thread scratch buffers (lidard.dsp.scratch) and the DSP paths that write into them."""

from __future__ import annotations

import threading

import numpy as np

from lidard.dsp import scratch as scratch_mod
from lidard.dsp.chain import measure_peaks
from lidard.dsp.rangefft import RangeFFT
from lidard.dsp.scratch import scratch


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
