"""Is a detected peak one surface? The single-tone residual test for unresolved returns (issue 14).

Two surfaces closer than the range resolution c / (2B) (eq. 2-3: 17.4 mm at B = 8.6 GHz; the frame
DSP's cell is c / (2 gamma T_used), 19.4 mm with 90 % of the ramp) give two tones less than a bin
apart. Their sum is one peak, at a range between the two, that the -6 dB width test of
:mod:`lidard.dsp.cfar` cannot see below ~1.3 bins: the lobe widens by a fraction of a bin, as much
as a single tone's sampled lobe changes with its sub-bin position. What does change is the SHAPE:
one tone's spectrum near its peak is exactly the window's DTFT centred on the tone, X_k = a W(k - mu),
while two tones beat against each other over the ramp (an envelope that swings and a phase that
bends), which no single W(k - mu) reproduces.

The test: with mu the estimator's sub-bin frequency, fit the one complex amplitude a per ramp by
least squares on the 2 h + 1 bins around the peak; the residual R = sum |X_k - a W(k - mu)|^2 is
noise only for one tone (E[R] ~ (2h + 1) sigma^2, sigma^2 the white floor per cell from the median of
the whole spectrum: :func:`floor_noise`), and grows with the square of the second tone's amplitude
for two. A peak is unresolved when R exceeds ``NOISE_FACTOR`` x that (on the simulated bench single
surfaces from 0.8 to 12 m stayed under 4x in ~25,000 peaks) and ``MODEL_FLOOR`` x the peak's own
energy (the single-tone model's own error on a very strong return: linearization residue, phase
noise). Either ramp's verdict flags the point (lidard.dsp.frame).

Limit: two returns half a cell apart that are IN PHASE at the ramps' centre (the relative phase there
is 2 pi nu_mid d_tau on both ramps) sum to one tone with a tapered envelope, ~-30 dB of the peak away
from one tone's shape: under the noise at the bench's ~35 dB, such a pixel gives one valid point
between the two surfaces (tests/dsp/test_dsp_resolve.py, tests/e2e/test_e2e_unresolved.py: ~5 % of
pixels at 10 mm). A cell apart (20 mm) every pair is flagged.
The test runs on the plain range FFT's spectra (lidard.dsp.frame); the phase-noise compensated front
end (lidard.dsp.pnframe) keeps the -6 dB width test only.
Peaks within ``DC_BINS`` of DC (or of Nyquist) are not judged: their image overlaps the fit.

Pure numpy.
"""

from __future__ import annotations

import numpy as np

from .dtft import _window_dtft_bins

HALF_BINS = 3           # the fit uses the peak's bin and 3 on each side (the Hann main lobe is +-2)
# another detection of the same ramp this far away (in bins) has its main lobe in the fit's cells: it
# joins the fit as a second known tone (from NEIGHBOUR_MIN_BINS on: nearer, its leakage also biases
# the first tone's frequency, and the single-tone verdict stands)
NEIGHBOUR_MIN_BINS = 4.0
NEIGHBOUR_MAX_BINS = HALF_BINS + 3.0
NOISE_FACTOR = 5.0      # residual / expected noise residual above which a peak is not one tone
MODEL_FLOOR = 3e-3      # residual / peak energy the one-tone model may leave on a strong return (-25 dB)
DC_BINS = 4


def single_tone_residual(spec: np.ndarray, index: np.ndarray, frac_bins: np.ndarray, *, window: str,
                         n_samples: int, zero_pad: int = 1, iq: bool = False,
                         average_axis: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(residual power, fitted peak energy) of each detection, summed over the averages.

    ``spec`` (batch..., [averages,] n_bins) complex, RangeFFT layout; ``index`` (batch..., K) the
    detections' spectrum indices (any value where invalid); ``frac_bins`` (batch..., K) their refined
    signed frequencies in bins of the spectrum's grid.
    """
    s3 = _by_ramp(spec, average_axis)
    index = np.asarray(index)
    k = index.shape[-1]
    b = np.repeat(np.arange(s3.shape[0]), k)
    resid, energy = _residual_at(s3, b, index.reshape(-1), np.asarray(frac_bins, dtype=np.float64).reshape(-1),
                                 window=window, n_samples=n_samples, zero_pad=zero_pad, iq=iq)
    return resid.reshape(index.shape), energy.reshape(index.shape)


def _by_ramp(spec: np.ndarray, average_axis: int | None) -> np.ndarray:
    """``spec`` as (pixels, averages, n_bins) (a view in the frame DSP's layout)."""
    s = np.asarray(spec)
    s = s[..., None, :] if average_axis is None else np.moveaxis(s, average_axis, -2)
    return s.reshape((-1,) + s.shape[-2:])


def _residual_at(s3: np.ndarray, b: np.ndarray, index: np.ndarray, frac: np.ndarray, *, window: str,
                 n_samples: int, zero_pad: int, iq: bool, frac2: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The single-tone fit of detections (pixel ``b``, spectrum index, refined bin), one each: only
    the 2 h + 1 cells around each peak are read (issue 18: not the detection slots that are empty).
    ``frac2``: a neighbouring detection's refined bin per detection (NaN: none), fitted jointly as a
    second known tone, so that its lobe in these cells is not counted as the peak's misfit."""
    n_avg, n_bins = s3.shape[-2:]
    n_fft = n_bins if iq else 2 * (n_bins - 1)
    offs = np.arange(-HALF_BINS, HALF_BINS + 1)
    k = np.clip(index[:, None] + offs, 0, n_bins - 1)                 # (m, 2h+1)
    kbin = (k - n_fft // 2) if iq else k                              # signed bins of each cell
    w = _window_dtft_bins(window, n_samples, (kbin - frac[:, None]) / zero_pad)
    # (averages, m, 2h+1): the sums over the averages run along the first axis, one after the other
    x = s3[b[None, :, None], np.arange(n_avg)[:, None, None], k[None, :, :]]
    ww = np.sum(np.abs(w) ** 2, axis=-1)                             # (m,)
    proj = np.sum(x * np.conj(w)[None, :, :], axis=-1)               # (averages, m)
    energy = np.abs(proj) ** 2 / np.where(ww > 0, ww, 1.0)[None, :]
    fitted = energy
    if frac2 is not None and np.isfinite(frac2).any():
        two = np.isfinite(frac2)
        w2 = _window_dtft_bins(window, n_samples, (kbin[two] - frac2[two, None]) / zero_pad)
        fitted = energy.copy()
        fitted[:, two] = _two_tone_energy(x[:, two], w[two], w2)
    resid = np.sum(np.abs(x) ** 2, axis=-1) - fitted
    return np.maximum(resid, 0.0).sum(axis=0), energy.sum(axis=0)


def _two_tone_energy(x: np.ndarray, w1: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """Energy of ``x`` (averages, m, cells) in the span of the two tone shapes w1, w2 (m, cells):
    the least-squares projection b^H G^-1 b with the 2 x 2 Gram matrix G and b = (x.w1*, x.w2*)."""
    g11, g22 = np.sum(np.abs(w1) ** 2, axis=-1), np.sum(np.abs(w2) ** 2, axis=-1)
    g12 = np.sum(w2 * np.conj(w1), axis=-1)                           # <w2, w1>
    det = np.maximum(g11 * g22 - np.abs(g12) ** 2, 1e-300)
    b1, b2 = np.sum(x * np.conj(w1), axis=-1), np.sum(x * np.conj(w2), axis=-1)
    quad = g22 * np.abs(b1) ** 2 + g11 * np.abs(b2) ** 2 - 2 * np.real(np.conj(b1) * g12 * b2)
    return quad / det


def _neighbours(frac: np.ndarray, valid: np.ndarray, b: np.ndarray, slot: np.ndarray, zero_pad: int) -> np.ndarray:
    """Per tested detection, the refined bin of the nearest other detection of its ramp within
    [NEIGHBOUR_MIN_BINS, NEIGHBOUR_MAX_BINS] bins, or NaN."""
    f = frac[b]                                                       # (m, K)
    d = np.abs(f - frac[b, slot][:, None]) / zero_pad
    near = valid[b] & (np.arange(frac.shape[1]) != slot[:, None]) & (d >= NEIGHBOUR_MIN_BINS) & (d <= NEIGHBOUR_MAX_BINS)
    j = np.argmin(np.where(near, d, np.inf), axis=1)
    return np.where(near.any(axis=1), f[np.arange(len(b)), j], np.nan)


def floor_noise(spec: np.ndarray, average_axis: int | None, power: np.ndarray | None = None) -> np.ndarray:
    """Mean noise power per cell of each ramp, from the median of its whole spectrum (exponential
    cells: median = ln 2 x mean; a few peaks do not move it), averaged over the averages.
    ``power``: re^2 + im^2 of ``spec`` when the caller has it already (|spec|^2 up to rounding)."""
    p = np.abs(np.asarray(spec)) ** 2 if power is None else power
    med = _median_last(p) / np.log(2.0)
    return med if average_axis is None else med.mean(axis=average_axis)


def _median_last(p: np.ndarray) -> np.ndarray:
    """np.median over the last axis of a finite array, by one partition (issue 18: np.median also
    partitions for its NaN check and was a fifth of the frame DSP; the spectra here are finite)."""
    n = p.shape[-1]
    h = n // 2
    if n % 2:
        return np.partition(p, h, axis=-1)[..., h]
    part = np.partition(p, (h - 1, h), axis=-1)
    return (part[..., h - 1] + part[..., h]) * 0.5


def unresolved(spec: np.ndarray, index: np.ndarray, frac_bins: np.ndarray, valid: np.ndarray,
               noise: np.ndarray, *, window: str, n_samples: int, zero_pad: int = 1, iq: bool = False,
               average_axis: int | None = None, power: np.ndarray | None = None) -> np.ndarray:
    """Detections whose peak is not one tone (module docstring); (batch..., K) bool. ``power``:
    re^2 + im^2 of ``spec`` if the caller has it (the detection chain does), else computed here."""
    idx = np.where(valid, index, 0)
    frac = np.where(valid, frac_bins, 0.0)
    s3 = _by_ramp(spec, average_axis)
    n_avg, n_bins = s3.shape[-2:]
    edge = np.abs(frac) / zero_pad
    judged = (edge >= DC_BINS) & (edge <= n_samples / 2 - DC_BINS) if not iq else (edge >= DC_BINS)
    judged &= (idx - HALF_BINS >= 0) & (idx + HALF_BINS <= n_bins - 1)
    out = np.zeros(idx.shape, dtype=bool)
    k = idx.shape[-1] if idx.ndim else 1
    b, slot = np.nonzero((valid & judged).reshape(-1, k))     # only these are tested
    if b.size == 0:
        return out
    resid, energy = _residual_at(s3, b, idx.reshape(-1, k)[b, slot], frac.reshape(-1, k)[b, slot],
                                 window=window, n_samples=n_samples, zero_pad=zero_pad, iq=iq,
                                 frac2=_neighbours(frac.reshape(-1, k), np.asarray(valid).reshape(-1, k), b, slot,
                                                   zero_pad))
    # the floor of the pixels tested (all of them, or fewer: then only theirs is computed)
    pix, at = np.unique(b, return_inverse=True)
    p3 = None if power is None else _by_ramp(power, average_axis)
    if pix.size == s3.shape[0]:
        floor = floor_noise(s3, 1, p3)[at]
    else:
        floor = floor_noise(s3[pix], 1, None if p3 is None else p3[pix])[at]
    expected = NOISE_FACTOR * (2 * HALF_BINS + 1) * n_avg * floor
    out.reshape(-1, k)[b, slot] = (resid > expected) & (resid > MODEL_FLOOR * energy)
    return out
