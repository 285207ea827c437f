"""Cramer-Rao lower bound for the frequency of one tone in white Gaussian noise (Rife & Boorstyn,
1974), the yardstick of the sub-bin estimators (estimators.py) and of the range precision
(eq. 2-1: sigma_d = c sigma_f / (2 gamma)).

Two SNR conventions, kept apart by name:

* per-sample SNR (``snr_linear``): signal power / noise variance per sample.  Complex tone
  A exp(j w n) in complex noise of variance sigma^2: A^2 / sigma^2.  Real tone A cos(w n + phi)
  in real noise of variance sigma^2: (A^2 / 2) / sigma^2.
* post-FFT SNR (``post_fft_snr_linear``): power of the peak bin over the mean noise power of one
  bin, for an on-bin tone with a RECTANGULAR window and no zero-padding.  Complex: N A^2 / sigma^2;
  real: N A^2 / (4 sigma^2).  This is what benchmarks/speed_vs_error.py sweeps.

Bounds, frequency in FFT bins of the unpadded N-point grid (multiply by (fs / N)^2 for Hz^2):
    complex:  var >= 6 N / ((2 pi)^2 snr (N^2 - 1))
    real:     var >= 12 N / ((2 pi)^2 snr (N^2 - 1))    (half the per-sample power is in the image)
    either, in post-FFT SNR rho:  var >= 6 N^2 / ((2 pi)^2 rho (N^2 - 1))  ~= 3 / (2 pi^2 rho)
The real-tone bound is the asymptotic one (tone well away from DC and Nyquist).
"""

from __future__ import annotations

import numpy as np

from lidard.dsp.spectrum.window import DspInputError


def _check(snr: object, n: int, name: str) -> np.ndarray:
    s = np.asarray(snr, dtype=np.float64)
    if np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise DspInputError(f"{name} must be positive and finite, got {snr!r}")
    if int(n) != n or n < 2:
        raise DspInputError(f"n={n!r} must be an integer >= 2")
    return s


def crlb_freq_var(snr_linear: object, n: int, *, real: bool = False, fs_hz: float | None = None) -> np.ndarray:
    """Rife-Boorstyn bound on var(frequency) from the per-sample SNR.

    Returns bins^2 (N-point grid), or Hz^2 if ``fs_hz`` is given.
    """
    s = _check(snr_linear, n, "snr_linear")
    var_bins = (12.0 if real else 6.0) * n / ((2.0 * np.pi) ** 2 * s * (n * n - 1.0))
    return var_bins if fs_hz is None else var_bins * (fs_hz / n) ** 2


def crlb_freq_var_post_fft(post_fft_snr_linear: object, n: int, *, fs_hz: float | None = None) -> np.ndarray:
    """The same bound from the post-FFT SNR (module docstring); bins^2, or Hz^2 with ``fs_hz``."""
    rho = _check(post_fft_snr_linear, n, "post_fft_snr_linear")
    var_bins = 6.0 * n * n / ((2.0 * np.pi) ** 2 * rho * (n * n - 1.0))
    return var_bins if fs_hz is None else var_bins * (fs_hz / n) ** 2


def post_fft_snr(snr_linear: object, n: int, *, real: bool = False) -> np.ndarray:
    """Per-sample SNR -> post-FFT SNR (rectangular window, on-bin tone): N snr, or N snr / 2 real."""
    s = _check(snr_linear, n, "snr_linear")
    return s * n / (2.0 if real else 1.0)


def crlb_tones_freq_var(freq_bins: object, amplitudes: object, phases: object, n: int, sigma: float, *,
                        real: bool = True) -> np.ndarray:
    """Cramer-Rao bound on the frequencies of K tones observed together (bins^2 of the n-point grid),
    by the Fisher information of the full model: ``freq_bins`` (K,) common to the L records,
    ``amplitudes`` and ``phases`` (L, K) each record's own (nuisance parameters), white noise of
    standard deviation ``sigma`` per sample (per real and imaginary part for complex tones). Two tones
    a few bins apart hardly couple (each near its one-tone bound); under a bin apart they do."""
    f = np.asarray(freq_bins, dtype=np.float64)
    a = np.atleast_2d(np.asarray(amplitudes, dtype=np.float64))
    ph = np.atleast_2d(np.asarray(phases, dtype=np.float64))
    if not (sigma > 0 and np.all(np.isfinite(f)) and a.shape == ph.shape and a.shape[-1] == f.size):
        raise DspInputError(f"need K frequencies and (L, K) amplitudes and phases, sigma > 0; got {f.shape}, "
                            f"{a.shape}, {ph.shape}, sigma={sigma!r}")
    n_rec, k = a.shape
    t = np.arange(n, dtype=np.float64)
    w = 2 * np.pi * f / n
    cols = []     # per record: d/dA_k, d/dphi_k (only that record's rows), then d/dw_k (every record)
    arg = w[None, :, None] * t + ph[:, :, None]                              # (L, K, n)
    e = np.cos(arg) if real else np.exp(1j * arg)
    de = -np.sin(arg) if real else 1j * np.exp(1j * arg)
    for r in range(n_rec):
        for j in range(k):
            for v in (e[r, j], a[r, j] * de[r, j]):
                c = np.zeros((n_rec, n), dtype=e.dtype)
                c[r] = v
                cols.append(c.ravel())
    for j in range(k):
        cols.append((a[:, j, None] * t * de[:, j]).ravel() * 2 * np.pi / n)
    d = np.stack(cols, axis=-1)
    fim = np.real(d.conj().T @ d) / sigma ** 2
    cov = np.linalg.inv(fim)
    return np.diag(cov)[-k:].copy()
