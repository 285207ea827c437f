"""Do the fitted tones explain each peak? The model-order test of a ramp's detections (§2.4).

Two surfaces closer than the range resolution c / (2B) give two tones less than a bin apart: one
peak, one detection. The tones the detector found are fitted (:mod:`.tones`); what is left around
each peak is noise if they are all there, and grows with the square of a missing tone's amplitude
if one hides under a peak: a test of the model order (the detected K tones against more), not of
a peak's width or shape by rule.

The statistic: the 2h + 1 windowed spectrum cells around a detection, in each of the pixel's L
records, less the least-squares fit of the window's DTFT W(k - f_j) at every detected tone j whose
main lobe reaches those cells (its complex amplitude per record fitted, its frequency the joint
estimate). The window correlates neighbouring cells: their noise covariance is sigma^2 R with
R_mn = sum_t w_t^2 exp(-j 2 pi (m - n) t / N) / sum_t w_t^2 (a property of the window alone), so
the residual is whitened by R's Cholesky factor. With sigma^2 the noise power per cell (the median
of the ramp's whole spectrum / ln 2: a few peaks do not move it), twice the whitened residual power
over sigma^2 is chi-square with 2 (M - K_loc) L degrees of freedom under "these tones and white
noise" (M = 2h + 1 cells, K_loc tones fitted there), less K_loc for their fitted frequencies. A detection is UNRESOLVED when the statistic
exceeds that distribution's upper ``level`` quantile: ``level`` is the probability that a clean
return is flagged, a stated rate, not a tuned factor.

The tone model is not exact on a strong return (the chirp's linearization residue, phase noise,
the receiver's own harmonics): its misfit scales with the return's power. ``MODEL_ERROR`` is that
relative misfit (residual / fitted energy in the cells) the model allows; a residual under it is
not evidence of a second surface.

Peaks within ``DC_BINS`` of DC (or of Nyquist) are not judged: their mirror image sits in the cells.
Pure numpy; where numba is installed the least-squares fits of the cells are compiled passes
(lidard.dsp.spectrum._kernels_fit: the same sums to rounding).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import gammainccinv

from ..spectrum import jit
from ..spectrum.windowdtft import _window_dtft_bins, _window_dtft_grid
from ..spectrum.window import get_window


def chi2_isf(p: float | np.ndarray, dof: float | np.ndarray) -> np.ndarray:
    """The chi-square quantile exceeded with probability ``p`` at ``dof`` degrees of freedom
    (scipy.stats.chi2.isf through the inverse regularized gamma function: scipy.stats costs ~0.5 s of
    start-up on every scan, scipy.special is already loaded)."""
    return np.asarray(2.0 * gammainccinv(np.asarray(dof, dtype=float) / 2.0, p), dtype=np.float64)

#: cells on each side of a detection that the test reads (the Hann main lobe is +-2 bins: a second
#: tone hidden under the peak leaves its misfit inside +-3)
HALF_BINS = 3
#: relative misfit of the tone model on a strong single return (linearization residue, phase noise:
#: -25 dB of the peak's energy in the cells on the simulated bench's calibrated chirp)
MODEL_ERROR = 3e-3
#: peaks this near DC or Nyquist (bins) are not judged (their mirror image overlaps the cells)
DC_BINS = 4


@lru_cache(maxsize=16)
def _whitener(window: str, n: int, m: int) -> np.ndarray:
    """L^-1 (m, m) with L L^H = R, R the windowed cells' noise correlation (module doc)."""
    w2 = get_window(window, n) ** 2
    t = np.arange(n)
    lags = np.arange(m)
    rho = (np.exp(-2j * np.pi * np.outer(lags, t) / n) @ w2) / w2.sum()
    r = np.empty((m, m), dtype=np.complex128)
    for i in range(m):
        for j in range(m):
            r[i, j] = rho[i - j] if i >= j else np.conj(rho[j - i])
    return np.linalg.inv(np.linalg.cholesky(r))


def order_statistic(spec: np.ndarray, index: np.ndarray, frac: np.ndarray, valid: np.ndarray, noise: np.ndarray,
                    *, window: str, n_samples: int, zero_pad: int = 1, iq: bool = False,
                    rows: np.ndarray | None = None,
                    freq_params: int | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per detection (P, K): (2 x whitened residual / sigma^2, its degrees of freedom, the residual
    and the fitted energy, both in power units of ``spec``). ``spec`` (P, L, n_bins) complex in
    RangeFFT layout, ``index`` its detections' cells, ``frac`` their refined signed frequencies in bins
    of the spectrum grid, (P, K) or per record (P, L, K) (a moving return's beat moves between the
    records), ``noise`` (P,) the noise power per cell. Detections not judged: NaN. ``rows`` (P,): the
    pixels' rows of ``spec`` when it holds more (read in place, not gathered). ``freq_params``: the
    parameters each tone's frequencies were fitted with (the degrees of freedom lose that many a
    tone), one number or one a pixel (P,); None: one a record for ``frac`` (P, L, K), one for (P, K)."""
    _, l_n, n_bins = spec.shape
    k = index.shape[-1]
    p_n = index.shape[0]
    rows = np.arange(p_n) if rows is None else np.asarray(rows)
    # a pixel's frequencies (P, K), common to its records: the window's DTFT once a pixel, not a record
    fr = np.asarray(frac, dtype=np.float64)[:, None, :] if np.ndim(frac) == 2 else np.asarray(frac, dtype=np.float64)
    f_mean = fr.mean(axis=1)
    n_fft = n_bins if iq else 2 * (n_bins - 1)
    m = 2 * HALF_BINS + 1
    stat = np.full((p_n, k), np.nan)
    dof = np.zeros((p_n, k))
    resid = np.full((p_n, k), np.nan)
    energy = np.full((p_n, k), np.nan)
    edge = np.abs(f_mean) / zero_pad
    judged = valid & (edge >= DC_BINS) & (index - HALF_BINS >= 0) & (index + HALF_BINS <= n_bins - 1)
    if not iq:
        judged &= edge <= n_samples / 2 - DC_BINS
    b, slot = np.nonzero(judged)
    if b.size == 0:
        return stat, dof, resid, energy
    offs = np.arange(-HALF_BINS, HALF_BINS + 1)
    cells = index[b, slot][:, None] + offs                                    # (q, m)
    kbin = (cells - n_fft // 2) if iq else cells
    x = spec[rows[b][:, None, None], np.arange(l_n)[None, :, None], cells[:, None, :]]   # (q, L, m)
    # the tones in the model at these cells: every valid detection of the ramp whose main lobe
    # (+-2 bins for Hann; +-(HALF_BINS + 3) is generous for every window here) reaches them
    near = valid[b] & (np.abs(f_mean[b] - f_mean[b, slot][:, None]) / zero_pad <= HALF_BINS + 3)   # (q, K)
    f_all = np.where(near[:, None, :], fr[b], 0.0)                            # (q, L, K)
    # the cells are consecutive: the window's DTFT from the first one on (lidard.dsp.spectrum.dtft)
    cols = _window_dtft_grid(window, n_samples, (kbin[:, :1, None] - f_all) / zero_pad, m, zero_pad)
    cols = np.broadcast_to(np.where(near[:, None, :, None], cols, 0.0), (b.size, l_n, k, m))   # (q, L, K, m)
    white = _whitener(window, n_samples, m)
    kern = jit.kernels(0)
    got = None if kern is None else _order_fit_compiled(kern, x, cols, near, white)
    if got is not None:
        fit, total = got
    else:
        fit, total = _order_fit(x, cols, near, white)
    r = np.maximum(total - fit, 0.0)
    k_loc = near.sum(axis=1)
    stat[b, slot] = 2.0 * r / noise[b]
    # each record's amplitudes and (when given per record) frequencies were fitted
    if freq_params is None:
        freq_params = l_n if np.ndim(frac) == 3 else 1
    dof[b, slot] = 2.0 * (m - k_loc) * l_n - k_loc * np.broadcast_to(np.asarray(freq_params, dtype=float), (p_n,))[b]
    resid[b, slot] = r
    energy[b, slot] = fit
    return stat, dof, resid, energy


def _order_fit_compiled(kern, x: np.ndarray, cols: np.ndarray, near: np.ndarray,
                        white: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_order_fit` in one compiled pass (lidard.dsp.spectrum._kernels_fit.order_fit: the same
    sums to rounding), or None on a singular G (the numpy path then says so)."""
    fit, total = np.empty(x.shape[0]), np.empty(x.shape[0])
    ok = kern.order_fit(np.ascontiguousarray(x), np.ascontiguousarray(cols), np.ascontiguousarray(near),
                        np.ascontiguousarray(white), fit, total)
    return (fit, total) if ok else None


def _order_fit(x: np.ndarray, cols: np.ndarray, near: np.ndarray, white: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The whitened least squares of :func:`order_statistic`: (the fitted energy, the whitened cells'
    energy), both summed over the records, per detection (Q,). ``x`` (Q, L, M) the cells, ``cols``
    (Q, L, K, M) the tones' window DTFT there (zero for the tones not ``near``, (Q, K))."""
    k = cols.shape[2]
    xw = np.einsum("ij,qlj->qli", white, x)
    cw = np.einsum("ij,qlkj->qlki", white, cols)
    # least squares in the whitened cells, record by record: the absent tones' columns zero
    g = np.einsum("qlki,qlpi->qlkp", np.conj(cw), cw)
    on = near[:, None, :, None] & near[:, None, None, :]
    g = np.where(on, g, np.eye(k)[None, None])
    rhs = np.einsum("qlki,qli->qlk", np.conj(cw), xw)
    amp = np.linalg.solve(g, rhs[..., None])[..., 0]                          # (q, L, K)
    fit = np.real(np.einsum("qlk,qlk->q", np.conj(rhs), amp))
    total = np.sum(np.abs(xw) ** 2, axis=(1, 2))
    return fit, total


def unresolved(spec: np.ndarray, index: np.ndarray, frac: np.ndarray, valid: np.ndarray, noise: np.ndarray, *,
               level: float, window: str, n_samples: int, zero_pad: int = 1, iq: bool = False,
               rows: np.ndarray | None = None, freq_params: int | np.ndarray | None = None) -> np.ndarray:
    """Detections (P, K) whose cells the fitted tones do not explain at the stated ``level`` (module doc);
    ``freq_params``: as for :func:`order_statistic`."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"model-order level must be in (0, 1), got {level!r}")
    stat, dof, resid, energy = order_statistic(spec, index, frac, valid, noise, window=window,
                                               n_samples=n_samples, zero_pad=zero_pad, iq=iq, rows=rows,
                                               freq_params=freq_params)
    judged = np.isfinite(stat)
    limit = np.where(judged, chi2_isf(level, np.maximum(dof, 1.0)), np.inf)
    return judged & (stat > limit) & (resid > MODEL_ERROR * energy)


def median_last(p: np.ndarray) -> np.ndarray:
    """np.median over the last axis of a finite array, by one partition (np.median also partitions for
    its NaN check: a fifth of the frame DSP once; the spectra here are finite)."""
    n = p.shape[-1]
    h = n // 2
    if n % 2:
        return np.partition(p, h, axis=-1)[..., h]
    part = np.partition(p, (h - 1, h), axis=-1)
    return (part[..., h - 1] + part[..., h]) * 0.5


#: the noise floor is the median of every NOISE_STRIDE-th cell of a spectrum: far enough apart to be
#: independent under any window here, and hundreds of them (1 / sqrt(360) ~ 5 % on the scan's 1441-cell
#: spectra, inside the chi-square test's tolerance) at a quarter of the cost of all
NOISE_STRIDE = 4


def cell_noise(power: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """Mean noise power per cell of each pixel (P, L, n_bins) -> (P,): the median of each record's
    spectrum (exponential cells: median = ln 2 x mean; every NOISE_STRIDE-th cell, fewer than a
    hundred cells: all), averaged over the records. ``rows``: those pixels of ``power`` only (only
    their cells read are gathered)."""
    p = power[..., ::NOISE_STRIDE] if power.shape[-1] >= 100 * NOISE_STRIDE else power
    if rows is not None:
        p = p[rows]
    return (median_last(p) / np.log(2.0)).mean(axis=-1)


def _fit_near(spec, centre, frac, valid, *, half, window, n_samples, zero_pad, iq, rows):
    """The least-squares fit of the valid tones ``frac`` (P, L, K) to the cells around ``centre`` (P,):
    (cells (P, m), their values (P, L, m), the tones' columns (P, L, K, m), amplitudes (P, L, K))."""
    cells, x, cols = _cells_near(spec, centre, frac, valid, half=half, grid=(window, n_samples, zero_pad, iq), rows=rows)
    g = np.einsum("plki,plqi->plkq", np.conj(cols), cols)
    k = valid.shape[-1]
    on = valid[:, None, :, None] & valid[:, None, None, :]
    g = np.where(on, g, np.eye(k)[None, None]) + 1e-12 * np.eye(k)[None, None] * np.abs(g).max()
    rhs = np.einsum("plki,pli->plk", np.conj(cols), x)
    return cells, x, cols, np.linalg.solve(g, rhs[..., None])[..., 0]


def _cells_near(spec, centre, frac, valid, *, half, grid, rows):
    """What :func:`_fit_near` fits: (cells (P, m), their values (P, L, m), the valid tones' columns
    (P, L, K, m), zero for the others); ``grid``: (window, n_samples, zero_pad, iq) of the spectrum."""
    window, n_samples, zero_pad, iq = grid
    _, l_n, n_bins = spec.shape
    p_n = centre.shape[0]
    rows = np.arange(p_n) if rows is None else np.asarray(rows)
    n_fft = n_bins if iq else 2 * (n_bins - 1)
    first = centre - half
    m = 2 * half + 1
    cells = np.clip(first[:, None] + np.arange(m), 0, n_bins - 1)                      # (P, m)
    x = spec[rows[:, None, None], np.arange(l_n)[None, :, None], cells[:, None, :]]   # (P, L, m)
    f = np.where(valid[:, None, :], frac[:, None, :] if frac.ndim == 2 else frac, 0.0)     # (P, L or 1, K)
    k0 = (first - n_fft // 2) if iq else first
    # the window's DTFT on the consecutive cells from the first one (lidard.dsp.spectrum.dtft); a
    # cell clipped at the spectrum's edge reads the value of the cell it was clipped to
    cols = _window_dtft_grid(window, n_samples, (k0[:, None, None] - f) / zero_pad, m, zero_pad)
    if np.any(cells != first[:, None] + np.arange(m)):
        cols = np.take_along_axis(cols, (cells - first[:, None])[:, None, None, :], axis=-1)
    cols = np.where(valid[:, None, :, None], cols, 0.0)
    return cells, x, np.broadcast_to(cols, (p_n, l_n) + cols.shape[2:])                # (P, L, K, m)


def residual_near(spec: np.ndarray, centre: np.ndarray, frac: np.ndarray, valid: np.ndarray, *, half: int,
                  window: str, n_samples: int, zero_pad: int = 1, iq: bool = False,
                  rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(cells (P, 2 half + 1), their power less the fitted tones', averaged over the records): the
    windowed spectrum around ``centre`` (P,) cells with every valid tone of ``frac`` (P, L, K) fitted
    by least squares (amplitude per record) and taken out. Where a strong return's skirt hides a weak
    one from the detector, the weak one stands out here. ``rows``: as for :func:`order_statistic`."""
    kern = jit.kernels(0)
    if kern is not None:    # the fit and the residual in one compiled pass (the same sums to rounding)
        cells, x, cols = _cells_near(spec, centre, frac, valid, half=half, grid=(window, n_samples, zero_pad, iq),
                                     rows=rows)
        out = np.empty(cells.shape)
        if kern.residual_fit(np.ascontiguousarray(x), np.ascontiguousarray(cols), np.ascontiguousarray(valid), out):
            return cells, out
    cells, x, cols, amp = _fit_near(spec, centre, frac, valid, half=half, window=window, n_samples=n_samples,
                                    zero_pad=zero_pad, iq=iq, rows=rows)
    r = x - np.einsum("plk,plki->pli", amp, cols)
    return cells, (r.real ** 2 + r.imag ** 2).mean(axis=1)


def fitted_power(spec: np.ndarray, index: np.ndarray, frac: np.ndarray, valid: np.ndarray, *, window: str,
                 n_samples: int, zero_pad: int = 1, iq: bool = False,
                 rows: np.ndarray | None = None) -> np.ndarray:
    """Each valid tone's peak power (P, K) in ``spec``'s units, averaged over the records, from the joint
    least-squares fit of all of a ramp's tones (``frac`` (P, L, K), signed bins of the spectrum grid) to
    the cells around it: without the scalloping of its peak cell and without the neighbours' leakage,
    which moves a peak cell's power by several dB when two returns are a few cells apart."""
    peak = abs(complex(_window_dtft_bins(window, n_samples, np.zeros(1))[0])) ** 2
    out = np.zeros(index.shape)
    for k in range(index.shape[-1]):
        sel = valid[:, k]
        if not sel.any():
            continue
        r = np.flatnonzero(sel)
        amp = _fit_near(spec, index[r, k], frac[r], valid[r], half=HALF_BINS, window=window, n_samples=n_samples,
                        zero_pad=zero_pad, iq=iq, rows=r if rows is None else np.asarray(rows)[r])[3]
        out[r, k] = peak * (amp[..., k].real ** 2 + amp[..., k].imag ** 2).mean(axis=1)
    return out
