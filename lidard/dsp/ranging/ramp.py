"""One ramp's detections through the model: joint refinement, model-order test, a hidden return.

The frame DSP (:mod:`lidard.dsp.frame`) hands over a ramp's records, their windowed spectra and the
detector's cells with their one-tone estimates. Here

1. detections that share cells (another of the ramp within ``SKIRT_BINS``) are refined jointly
   (:mod:`.tones`: no estimate carries the others' leakage); a detection alone in its cells is
   refined as a lone return over the pixel's records (:mod:`.pixeltone`, the beat's drift included);
2. every detection's cells are tested against the fitted tones (:mod:`.order`, at ``level``);
3. where the fitted tones do not explain a peak and the ramp has a free slot, the model grows by one
   tone: the records less the fitted tones are searched around that peak, the new tone is refined
   jointly with the others and the test is run again. When the grown model explains the cells and
   its tones are at least the ramp's resolution apart (one bin: c / (2 gamma T), eq. 2-3) the new
   tone is a detection (a weak return beside a strong one that the detector's threshold missed);
   closer than that the two cannot be told apart and the peak stays flagged unresolved. The new
   tone must also pass the detector's false-alarm rate ``pfa`` on its own: its cell's power, the
   fitted tones taken out, against the noise-only chi-square law of L averaged records.

A false extra return needs the test to fail on noise (probability ``level`` per detection) and the
grown model to pass: the rate is below ``level``. Pure numpy.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np

from ..detect.cfar import Detections
from ..spectrum.rangefft import RangeFFT, windowed_fft
from .order import HALF_BINS, MODEL_ERROR, cell_noise, chi2_isf, fitted_power, residual_near, unresolved
from .pixeltone import record_offsets, refine_pixel_tone
from .tones import ITERATIONS, refine_joint, subtract_tones

#: how far (bins) from a peak the fitted tones do not explain a hidden return is looked for: the
#: cells the test read, and one more
SEARCH_BINS = HALF_BINS + 1
#: two tones closer than this (bins of the ramp's own grid, c / (2 gamma T) each) are one unresolved
#: peak. The two-tone Cramer-Rao bound on each frequency, against one tone's (averaged over their
#: relative phase; lidard.dsp.ranging.crlb.crlb_tones_freq_var): 1.02x at 3 bins, 1.1x at 1.5, 1.3x at 1.25,
#: 1.7x at 1, 2.4x at 0.75, 4.3x at 0.5: from here on down the pair's ranges are no longer points of
#: the instrument's precision
RESOLUTION_BINS = 1.25
#: the grown model's refinement may move each tone this far (bins): a peak of two tones under a bin
#: or two apart was estimated between them, up to a bin from either
GROW_REACH_BINS = 1.25
#: a return this close (bins) to a much stronger one sits on its skirt and in the detector's reference
#: cells (OS-CFAR's loss beside a strong peak): the cells around each detection, the fitted tones taken
#: out, are searched again at the detector's pfa
SKIRT_BINS = 8


class RampModel(NamedTuple):
    """How a ramp's detections are refined and judged (:func:`refine_ramp`): the range FFT's ``window``,
    the model-order test's ``level``, the detector's per-ramp ``pfa``, ``ml`` and ``max_drift``."""

    window: str
    level: float
    pfa: float
    ml: bool = True
    max_drift: float = 0.0


def refine_ramp(ramp: np.ndarray, spec: np.ndarray, power: np.ndarray, det: Detections, frac: np.ndarray, *,
                rf: RangeFFT, model: RampModel) -> tuple[np.ndarray, Detections]:
    """(refined frac (P, K); the detections with ``unresolved`` set and hidden returns added).

    ``ramp`` (P, L, N) the records, ``spec``/``power`` (P, L, n_bins) their windowed spectra and
    |spec|^2, ``det`` (P, K) the detector's, ``frac`` (P, K) one estimate per detection and pixel
    (signed fractional bins of the spectrum grid). The pixel's records share each tone's frequency
    and have their own complex amplitudes (the speckle, the record's start phase): the likelihood of
    the frequencies is the sum of the records' projections (:func:`.tones.refine_joint`), maximised
    once per pixel. ``ml``: ``frac`` is only a start (:func:`lidard.dsp.ranging.estimators.pooled_jacobsen`)
    and a detection alone in its cells (no other of the ramp within SKIRT_BINS: :func:`_isolated`) is
    refined by that likelihood too (the ``newton`` estimator), and where such a lone return shares its
    ramp with other returns, however far, all of them are then refined jointly (the others' leakage in
    the model); else ``frac`` is the selected estimator's mean over the records and only detections
    that share cells are refined, jointly. ``max_drift``: the largest change of a lone return's beat from one record to the
    next (bins of the N-point grid) inside the speed band: it is fitted with the frequency
    (:mod:`.pixeltone`), which is then the beat at the pixel's middle record, and kept where its
    likelihood ratio passes ``level`` (:func:`_drift_seen`; else the common frequency, whose tests
    take the window's DTFT once a pixel). ``model``: the window, level, pfa, ml and max_drift (:class:`RampModel`)."""
    window, level, pfa, ml, max_drift = model
    zp, (p_n, l_n, n) = rf.zero_pad, ramp.shape
    k = det.valid.shape[-1]
    out = np.array(frac, dtype=np.float64)
    valid = det.valid
    count = np.count_nonzero(valid, axis=-1)
    flags = np.zeros(valid.shape, dtype=bool)
    judged = np.flatnonzero(count > 0)
    noise = np.zeros(p_n)           # the noise power per cell of the judged pixels
    if judged.size:
        noise[judged] = cell_noise(power, None if judged.size == p_n else judged)
    drift = np.zeros(out.shape)     # (P, K) a lone return's beat drift per record (bins of the spectrum grid)
    alone = _isolated(out / zp, valid)     # no other detection of the ramp within SKIRT_BINS
    if ml:
        pix, slot = np.nonzero(alone)
        if pix.size:
            fit = refine_pixel_tone(ramp, out[pix, slot] / zp, max_drift=max_drift, rows=pix)
            moving = _drift_seen(fit.gain, noise[pix], rf, level)
            out[pix, slot] = np.where(moving, fit.freq, fit.common) * zp
            drift[pix, slot] = np.where(moving, fit.drift, 0.0) * zp
    near = valid & ~alone              # detections that share cells with another: fitted jointly
    several = np.flatnonzero(np.count_nonzero(near, axis=-1) >= 2)
    if several.size:
        if ml:  # each tone alone first (as the one-tone Newton started the joint fit): the three-bin
            # start carries a neighbour's leakage (~0.1-0.2 bin two cells apart), beyond the joint fit's few steps
            pix, slots = np.nonzero(near[several])
            out[several[pix], slots] = refine_pixel_tone(ramp, out[several[pix], slots] / zp,
                                                         rows=several[pix]).freq * zp
        out[several] = refine_joint(ramp[several], out[several] / zp, near[several]) * zp
    # Every return of a ramp is in each of its records, however far from the others. A lone return's
    # likelihood (one sinusoid in white noise) reads the others through the record's own rectangular
    # window, whose leakage falls only 6 dB an octave (-37 dB at 25 bins): a return 20 dB under a
    # stronger one 20-30 bins away came out 0.2-0.4 mm off, 15 of its standard deviations, and its
    # model-order test then flagged it. Where a ramp holds a lone return beside others, all of them are
    # fitted together (the others' leakage in the model); a moving lone return keeps its drift (the
    # joint model has none) and stays out.
    fixed = valid & (drift == 0)
    mixed = np.flatnonzero((np.count_nonzero(fixed, axis=-1) >= 2) & (alone & fixed).any(axis=-1))
    if ml and mixed.size:
        out[mixed] = refine_joint(ramp[mixed], out[mixed] / zp, fixed[mixed]) * zp
    if judged.size == 0:
        return out, replace(det, unresolved=flags)
    test = dict(level=level, window=window, n_samples=n, zero_pad=zp, iq=rf.iq)
    def freqs(pix: np.ndarray, ks: slice) -> tuple[np.ndarray, np.ndarray | None]:
        """The frequencies the tests fit on ``pix``: the pixel's (P, K), or where a lone return keeps
        its drift every record's (P, L, K), with each pixel's frequency parameters a tone (1 or 2)."""
        moved = drift[pix][:, ks].any(axis=-1)
        if not moved.any():
            return out[pix][..., ks], None
        rec = out[pix][:, None, ks] + record_offsets(l_n)[None, :, None] * drift[pix][:, None, ks]
        return rec, np.where(moved, 2, 1)

    # a detection alone in its cells is tested alone (its drift, if it has one, in its model); the
    # detections that share cells are tested together
    for k_ in range(k):
        pix = judged[alone[judged, k_]]
        if pix.size:
            ks = slice(k_, k_ + 1)
            f_t, params = freqs(pix, ks)
            flags[pix, ks] = unresolved(spec, det.index[pix, ks], f_t, valid[pix, ks], noise[pix], rows=pix,
                                        freq_params=params, **test)
    if several.size:
        f_t = out[several]              # no drift in a joint fit (``near`` slots have none)
        got = unresolved(spec, det.index[several], f_t, near[several], noise[several], rows=several,
                         freq_params=None, **test)
        flags[several] = np.where(near[several], got, flags[several])
    flags |= _too_close(out / zp, valid)
    det = replace(det, unresolved=flags)
    free = ~valid[judged].all(axis=-1)
    grow = flags[judged].any(axis=-1) & free
    if grow.any():
        pix = judged[grow]
        slot = np.argmax(det.unresolved[pix], axis=-1)
        out, det = _grow(_Records(ramp, spec, power), det, out,
                         _Search(pix, noise[pix], det.index[pix, slot], SEARCH_BINS * zp, slot), rf=rf, test=test, pfa=pfa)
    # a return on a stronger one's skirt that the detector missed: the cells around the strongest
    # detection, its fitted tones taken out, at the detector's pfa per cell
    skirt = free & ~grow
    if skirt.any():
        pix = judged[skirt]
        nz = noise[pix]
        ks = slice(0, max(1, int(np.count_nonzero(valid[pix], axis=-1).max()) if k > 1 else 1))
        ks = slice(None) if not np.all(valid[pix, ks].sum(axis=-1) == valid[pix].sum(axis=-1)) else ks
        cells, rp = residual_near(spec, det.index[pix, 0], freqs(pix, ks)[0], valid[pix, ks], half=SKIRT_BINS * zp,
                                  window=window, n_samples=n, zero_pad=zp, iq=rf.iq, rows=pix)
        best = np.argmax(rp, axis=-1)
        hit = rp[np.arange(pix.size), best] > _floor(nz, det.power[pix, 0], pfa, l_n)
        if hit.any():
            c2 = cells[np.arange(pix.size), best][hit]
            out, det = _grow(_Records(ramp, spec, power), det, out,
                             _Search(pix[hit], nz[hit], c2, zp, np.zeros(hit.sum(), np.int64)), rf=rf, test=test, pfa=pfa)
    # a ramp with several tones: their powers from the joint fit, not their peak cells (each other's
    # leakage moves a cell by dB): the pair likelihood compares the two ramps' amplitudes
    several = np.flatnonzero(np.count_nonzero(det.valid, axis=-1) >= 2)
    if several.size:
        pw = fitted_power(spec, det.index[several], out[several], det.valid[several], window=window, n_samples=n,
                          zero_pad=zp, iq=rf.iq, rows=several)
        power_all = det.power.copy()
        power_all[several] = np.where(det.valid[several], pw, det.power[several])
        det = replace(det, power=power_all, snr_db=10 * np.log10(np.maximum(power_all, 1e-300)
                                                                 / np.maximum(det.noise, 1e-300)))
    return out, det


def _drift_seen(gain: np.ndarray, noise: np.ndarray, rf: RangeFFT, level: float) -> np.ndarray:
    """Whether a lone return's fitted drift is a parameter of the model, not noise: the likelihood ratio
    of the drift against a common frequency, chi-square with one degree of freedom under no drift, past
    its ``level`` quantile (the model-order test's level). ``gain`` (P,) the fit's energy gained by the
    drift (:class:`.pixeltone.PixelFit`), ``noise`` (P,) the noise power per spectrum cell: the noise
    per sample is that over sum(w^2) / sum(w)^2 of the range FFT's window; a complex record's energy
    is N times its projection's, and its noise is split over two parts."""
    w = rf.window_samples
    sigma2 = np.maximum(noise, 1e-300) * w.sum() ** 2 / np.sum(w * w)
    stat = 2.0 * gain / (w.size * sigma2) if rf.iq else gain / sigma2
    return stat > chi2_isf(level, 1.0)


def _floor(noise: np.ndarray, peak: np.ndarray, pfa: float, l_n: int) -> np.ndarray:
    """The power a tone found in the residual must pass: the noise-only chi-square(2L) level ``pfa`` of
    a cell averaged over L records, and the misfit the model leaves on the ramp's strongest peak
    (MODEL_ERROR of its power: phase noise and linearization residue are not returns)."""
    return np.maximum(noise * chi2_isf(pfa, 2 * l_n) / (2 * l_n), MODEL_ERROR * peak)


def _isolated(f: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Detections (P, K) with no other of their ramp within SKIRT_BINS (``f`` in bins): their test cells,
    search cells and skirts are their own, so each is fitted and tested as a lone return."""
    d = np.abs(f[:, :, None] - f[:, None, :])
    both = valid[:, :, None] & valid[:, None, :] & ~np.eye(f.shape[-1], dtype=bool)[None]
    return valid & ~(both & (d <= SKIRT_BINS)).any(axis=-1)


def _too_close(f: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Detections (P, K) with another of their ramp nearer than RESOLUTION_BINS (``f`` in bins)."""
    d = np.abs(f[:, :, None] - f[:, None, :])
    both = valid[:, :, None] & valid[:, None, :] & ~np.eye(f.shape[-1], dtype=bool)[None]
    return (both & (d < RESOLUTION_BINS)).any(axis=-1)


class _Records(NamedTuple):
    """The records (P, L, N), their windowed spectra and |spec|^2 (P, L, n_bins)."""

    ramp: np.ndarray
    spec: np.ndarray
    power: np.ndarray


class _Search(NamedTuple):
    """Where :func:`_grow` looks for a hidden tone: on the pixels ``pix`` (each has a free slot), within
    ``half`` cells of ``centre``; ``noise`` their noise estimates and ``slot`` the detection whose
    noise the new one takes."""

    pix: np.ndarray
    noise: np.ndarray
    centre: np.ndarray
    half: int
    slot: np.ndarray


def _grow(rec: _Records, det: Detections, frac, search: _Search, *, rf: RangeFFT, test: dict[str, Any], pfa: float):
    """Step 3 of the module doc on the pixels of ``search``: a tone searched within its cells in the
    records less the fitted tones; ``frac`` (P, K)."""
    ramp, spec, power = rec
    pix, noise, centre, half, slot = search
    zp, (_, l_n, n) = rf.zero_pad, ramp.shape
    valid = det.valid[pix]
    f = frac[pix] / zp                                                         # (q, K)
    resid = subtract_tones(ramp[pix], f, valid)
    w = rf.window_samples
    rs = windowed_fft(resid.reshape(pix.size, l_n, n), w / w.sum(), rf.n_fft, "shifted" if rf.iq else "real")
    rp = (rs.real ** 2 + rs.imag ** 2).mean(axis=1)                             # (q, n_bins)
    free = np.argmin(valid, axis=-1)                                           # the first empty slot
    rows = np.arange(pix.size)
    cells = np.clip(centre[:, None] + np.arange(-half, half + 1), 0, rp.shape[-1] - 1)
    c2 = cells[rows, np.argmax(rp[rows[:, None], cells], axis=-1)]
    # the new tone is a detection by the detector's own rule (its cell's power, the others taken out)
    # and more than the strongest tone's model error (_floor)
    strong = rp[rows, c2] > _floor(noise, det.power[pix].max(axis=-1), pfa, l_n)
    f_new = f.copy()
    f_new[rows, free] = rf.index_to_bin(c2) / zp
    act = valid.copy()
    act[rows, free] = True
    f_new = refine_joint(ramp[pix], f_new, act, reach=GROW_REACH_BINS, iterations=2 * ITERATIONS)
    fm = f_new
    apart = np.abs(fm[rows, free][:, None] - fm) >= RESOLUTION_BINS
    apart = np.where(valid, apart, True).all(axis=-1)
    index = det.index[pix].copy()
    index[rows, free] = c2
    still = unresolved(spec, index, f_new * zp, act, noise, rows=pix, **test)
    ok = strong & apart & ~still.any(axis=-1)
    if not ok.any():
        return frac, det
    p, s, c = pix[ok], free[ok], c2[ok]
    fields = {name: getattr(det, name).copy() for name in ("index", "power", "noise", "snr_db", "valid", "harmonic",
                                                           "unresolved", "width_bins")}
    pw = power[p, :, c].mean(axis=-1)
    nz = fields["noise"][p, slot[ok]]
    fields["index"][p, s] = c
    fields["power"][p, s] = pw
    fields["noise"][p, s] = nz
    fields["snr_db"][p, s] = 10 * np.log10(np.maximum(pw, 1e-300) / np.maximum(nz, 1e-300))
    fields["valid"][p, s] = True
    fields["harmonic"][p, s] = False
    fields["width_bins"][p, s] = 0.0
    fields["unresolved"][p] = False     # the grown model explains every peak's cells
    frac = frac.copy()
    frac[p] = f_new[ok] * zp
    return frac, Detections(**fields)
