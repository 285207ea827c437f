"""The detection chain, written once: incoherent average -> OS-CFAR -> sub-bin estimate (§2.1, §4.4.3).

Every front end (the plain range FFT of :mod:`lidard.dsp.frame`, the phase-noise compensated composite
spectrum of :mod:`lidard.dsp.pnframe`, the single-batch :func:`measure_peaks` below)
hands this module a complex spectrum and a way to get the time-domain signals the estimator refines
(the ramps themselves, or the compensated ramps of each detection's delay). What happens next is the
same for all of them and lives only here.

Pure numpy: no I/O, no clock, no logging. This module imports the detector and the estimators, never a
front end (the front ends build on it: no import cycle, checked by import-linter).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from collections.abc import Callable

import numpy as np

from .detect.cfar import CfarSettings, Detections, cfar_detect_with
from .spectrum.jit import power as power_of
from .ranging.estimators import DEFAULT_METHOD, EstimatorName, estimate, estimate_rows, pooled_jacobsen
from .spectrum.rangefft import RangeFFT, check_samples
from .spectrum.scratch import scratch
from .spectrum.window import DspInputError

# (indices of the detections (..., K) with invalid slots at a harmless bin) -> (signals, signed peak
# bins for the estimator, precomputed spectrum or None)
RefineSignals = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray | None]]


@dataclass(frozen=True)
class ChainResult:
    """Refined fractional bins (batch..., K) (mean over ``average_axis``) and the CFAR detections;
    ``power``: |spec|^2 of every ramp (before the average), for the tests that read the spectrum again."""

    frac_bins: np.ndarray
    detections: Detections
    power: np.ndarray | None = None
    # the refined bins of every record (batch..., averages, K) before their mean (average_axis given)
    frac_records: np.ndarray | None = None


def detect_and_refine(spec: np.ndarray, refine: RefineSignals, *, cfar: CfarSettings, estimator: str | None,
                      average_axis: int | None = None, keep: np.ndarray | None = None, idle_index: int = 1,
                      power: np.ndarray | None = None) -> ChainResult:
    """``spec`` (batch..., [averages,] n_bins) complex in RangeFFT layout -> refined detections.

    ``average_axis``: the axis of ``spec`` holding the averages of one pixel (powers are averaged over
    it, incoherently, and the refined frequencies too); ``keep``: optional (n_bins,) mask of bins a
    detection may sit on (a |range| gate on a two-sided spectrum); ``idle_index``: the spectrum index
    given to the estimator for empty detection slots (their result is ignored); ``power``: |spec|^2 when
    the caller has it already (computed with the spectrum, :meth:`RangeFFT.spectrum_of`);
    ``cfar``: the detector's knobs (:class:`lidard.dsp.detect.cfar.CfarSettings`); its window, zero
    padding and layout (``iq``) are the spectrum's, and the estimator refines with them.
    ``estimator`` None: no refinement of each record; ``frac_bins`` is one three-bin estimate per pixel
    pooled over its records (:func:`lidard.dsp.ranging.estimators.pooled_jacobsen`), the start of the
    caller's refinement by the pixel's likelihood (``spec`` (P, L, n_bins), ``average_axis`` 1).
    """
    p_ramps = p = power_of(spec) if power is None else power
    if average_axis is not None:
        # the detector's noise model is the averaged cell's (Gamma(K), K the records averaged here): K
        # is this axis's length, nowhere else
        if cfar.records != 1:
            raise DspInputError(f"cfar.records={cfar.records} given with average_axis: the records averaged "
                                "are the axis's length")
        cfar = replace(cfar, records=int(p.shape[average_axis]))
        p = p.mean(axis=average_axis)
    window, zero_pad = cfar.window, cfar.zero_pad
    det = cfar_detect_with(p, cfar)
    if keep is not None:
        ok = det.valid & keep[np.maximum(det.index, 0)]
        det = replace(det, valid=ok, index=np.where(ok, det.index, -1))
    index = np.where(det.valid, det.index, idle_index)
    if average_axis is not None:
        ax = average_axis % spec.ndim
        index = np.broadcast_to(np.expand_dims(index, ax), spec.shape[:-1] + index.shape[-1:])
    valid = det.valid
    if average_axis is not None:
        valid = np.broadcast_to(np.expand_dims(valid, ax), index.shape)
    if estimator is None:
        if average_axis is None or average_axis % spec.ndim != 1 or spec.ndim != 3:
            raise ValueError("estimator=None (the pixel start) needs spec (pixels, records, bins) with average_axis=1")
        x, bins, _ = refine(np.where(det.valid, det.index, idle_index))
        start = pooled_jacobsen(spec, bins, window=window, n_samples=x.shape[-1], zero_pad=zero_pad, iq=cfar.iq)
        return ChainResult(frac_bins=np.where(det.valid, start, bins), detections=det, power=p_ramps)
    x, bins, spectrum = refine(index)
    frac = _refine_valid(x, bins, valid, spectrum, method=estimator, window=window, zero_pad=zero_pad)
    per_record = frac
    if average_axis is not None:
        frac = frac.mean(axis=average_axis % spec.ndim)
    return ChainResult(frac_bins=frac, detections=det, power=p_ramps,
                       frac_records=per_record if average_axis is not None else None)


def _refine_valid(x: np.ndarray, bins: np.ndarray, valid: np.ndarray, spectrum: np.ndarray | None,
                  **kw) -> np.ndarray:
    """The estimator on the valid detection slots only: a CAL pixel has about one return
    among ``max_returns`` slots, and an empty slot's refinement is thrown away. ``x`` (lead..., N),
    ``bins`` (lead..., K) or (lead...) and ``valid`` of the shape of ``bins``; empty slots give the
    slot's integer bin (never read: the detection is invalid)."""
    bins = np.asarray(bins)
    if valid.all() or bins.shape != valid.shape:
        return estimate(x, bins, spectrum=spectrum, **kw)
    out = np.array(bins, dtype=np.float64, order="C")  # a broadcast view's astype keeps odd strides
    if not valid.any():
        return out
    n = x.shape[-1]
    per_row = bins.ndim == x.ndim  # (lead..., K): K peaks per ramp
    k = bins.shape[-1] if per_row else 1
    flat_valid = valid.reshape(-1, k)
    rows, slots = np.nonzero(flat_valid)
    sp = None if spectrum is None else spectrum.reshape(-1, spectrum.shape[-1])
    fr = estimate_rows(x.reshape(-1, n), rows, bins.reshape(-1, k)[rows, slots], spectrum=sp, **kw)
    out.reshape(-1, k)[rows, slots] = fr
    return out


@dataclass(frozen=True)
class PeakMeasurements:
    """Refined detections of a batch of ramps, (batch..., K) each, strongest first.

    freq_hz / range_m are 0.0 where ``detections.valid`` is False.
    """

    freq_hz: np.ndarray
    range_m: np.ndarray
    detections: Detections


def measure_peaks(rf: RangeFFT, x: object, *, method: EstimatorName = DEFAULT_METHOD,
                  **cfar_kwargs) -> PeakMeasurements:
    """Range FFT, CFAR (``cfar_kwargs``: the other fields of :class:`lidard.dsp.detect.cfar.CfarSettings`;
    window, zero_pad and iq are taken from ``rf``; the range gate of ``rf`` limits the search) and sub-bin
    refinement of every detection with ``method``: the chain on one batch, no averaging."""
    a = check_samples(x, rf.n_samples)
    # the spectrum and its power never leave this call (the results are gathered from them): scratch
    shape = rf.spectrum_shape(a.shape[:-1])
    p = scratch("measure_peaks.power", shape, np.float64)
    spec = rf.spectrum_of(a, out=scratch("measure_peaks.spec", shape, np.complex128), power_out=p)
    gate = np.flatnonzero(rf.gate_mask)
    if gate.size == 0:
        raise DspInputError(f"range_gate_m={rf.range_gate_m} selects no bins")
    cfar_kwargs.setdefault("bin_range", (int(gate[0]), int(gate[-1])))
    # |range| gate on a two-sided spectrum: the contiguous bin_range above covers both signs
    keep = rf.gate_mask if (rf.iq and rf.range_gate_m is not None) else None
    cfar = CfarSettings(window=rf.window, zero_pad=rf.zero_pad, iq=rf.iq, **cfar_kwargs)
    res = detect_and_refine(spec, lambda idx: (a, rf.index_to_bin(idx), spec), cfar=cfar,
                            estimator=method, keep=keep, idle_index=int(rf.bin_to_index(1)), power=p)
    det, frac = res.detections, res.frac_bins
    freq_hz = np.where(det.valid, frac * rf.delta_f, 0.0)
    return PeakMeasurements(freq_hz=freq_hz, range_m=np.where(det.valid, rf.bin_to_range_m(frac), 0.0), detections=det)
