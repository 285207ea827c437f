"""CFAR detection of targets in FMCW range spectra (dissertation §2.4: detection needs SNR > 1 and a
chosen false-alarm rate; Fig. 2-8 sets the range limit where the signal meets the noise floor).

Detection on power spectra |X|^2 (exponentially distributed in white noise), batched over ramps:

* Cell averaging (CA): noise = mean of N reference cells; with N cells the threshold factor
  alpha = N (Pfa^(-1/N) - 1) gives the false-alarm probability Pfa exactly for exponential noise.
  Near the spectrum edges fewer cells exist; alpha is recomputed for the cells actually used.
* Ordered statistic (OS): noise = k-th smallest of N reference cells (robust to a second target in
  the reference window); alpha solves Pfa = prod_{i=0}^{k-1} (N - i) / (N - i + alpha) (Rohling 1983),
  found numerically once per (N, k, Pfa) and cached.  Edges use mirrored reference cells.  On a
  spectrum averaged over K records (``CfarSettings.records``) the cells are Gamma(K), and alpha solves
  the exact Pfa of that model instead (:mod:`lidard.dsp.detect.os_gamma`).

A detection is a cell above threshold that is also a local maximum.  Then:

* Side-lobe suppression: a local maximum that lies outside the main lobe of a stronger peak and
  below the worst-case leakage of the window at that distance (window.WindowInfo.leakage_envelope,
  times ``sidelobe_margin``) is a side-lobe, not a target, and is dropped.
* ``harmonic``: a detection at ~2x or ~3x (optionally aliased about Nyquist) the frequency of a
  peak stronger by ``harmonic_ratio_db`` is flagged (ADC clipping makes such ghosts).
* ``unresolved``: the -6 dB width of the peak exceeds ``unresolved_factor`` times the widest a
  single tone's sampled main lobe can look with this window: two (or more) targets closer than
  the resolution merged into one peak, or two peaks so close that each one's position is biased.

The default is OS-CFAR: CA-CFAR's mean is inflated by a second target a few bins away, which
masks both (two targets 3 bins apart vanish under CA with 2 guard cells).  The design Pfa assumes
independent cells (verified on independent exponential cells in tests/dsp/detect/test_dsp_cfar.py); a
Hann window correlates neighbouring bins and raised the realised rate about 1.8x in a check on
white noise (N = 512, Pfa = 1e-3), so configure Pfa with that margin.

Up to ``max_detections`` per ramp, STRONGEST FIRST, in fixed-shape (batch, K) arrays plus a
``valid`` mask.  Invalid slots hold index -1, power 0, SNR -inf.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Literal, get_args

import numpy as np

from lidard.dsp.spectrum import jit
from lidard.dsp.detect.os_cfar import (  # noqa: F401  (re-exported: the detector's public names and tests' reach)
    _OS_BLOCK, _check_pfa, _check_records, _mirror_padded, _noise_os, _os_detected, _os_screened, os_cfar_alpha, os_cfar_pfa,
)
from lidard.dsp.detect._post import (  # noqa: F401  (re-exported: tests' reach)
    _harmonic_ghosts, _single_tone_width, _strongest, _strongest_cells, _width_6db,
)
from lidard.dsp.spectrum.window import LEAKAGE_REACH_BINS, DspInputError, WindowName, check_window_name, window_info


CfarMethod = Literal["ca", "os"]
CFAR_METHODS: tuple[str, ...] = get_args(CfarMethod)


def ca_cfar_alpha(n_ref: int | np.ndarray, pfa: float) -> np.ndarray | float:
    """CA-CFAR threshold factor alpha = N (Pfa^(-1/N) - 1) for N reference cells."""
    _check_pfa(pfa)
    n = np.asarray(n_ref, dtype=np.float64)
    return n * (pfa ** (-1.0 / n) - 1.0)


@dataclass(frozen=True)
class Detections:
    """Fixed-shape CFAR output, (batch..., K) each; strongest first; invalid slots masked."""

    index: np.ndarray  # int64 index into the spectrum's last axis, -1 where invalid
    power: np.ndarray  # float64 peak power |X|^2
    noise: np.ndarray  # float64 local noise estimate (mean power per cell)
    snr_db: np.ndarray  # float64 10 log10(power / noise)
    valid: np.ndarray  # bool
    harmonic: np.ndarray  # bool: at ~2x/3x the frequency of a much stronger detection
    unresolved: np.ndarray  # bool: wider than the window's main lobe -> merged targets
    width_bins: np.ndarray  # float64 measured -6 dB width of the peak (bins of the spectrum grid)

    @property
    def targets(self) -> np.ndarray:
        """Valid detections that are not flagged as harmonic ghosts."""
        return self.valid & ~self.harmonic


def _sliding_sum(p: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum and count of p[..., i+lo : i+hi+1] (clipped to the array) for every i."""
    n = p.shape[-1]
    cs = np.concatenate([np.zeros(p.shape[:-1] + (1,)), np.cumsum(p, axis=-1)], axis=-1)
    i = np.arange(n)
    a = np.clip(i + lo, 0, n)
    b = np.clip(i + hi + 1, 0, n)
    return cs[..., b] - cs[..., a], (b - a).astype(np.float64)


def _noise_ca(p: np.ndarray, n_ref_side: int, n_guard: int, pfa: float) -> tuple[np.ndarray, np.ndarray | float]:
    lag_s, lag_n = _sliding_sum(p, -n_guard - n_ref_side, -n_guard - 1)
    lead_s, lead_n = _sliding_sum(p, n_guard + 1, n_guard + n_ref_side)
    count = lag_n + lead_n
    noise = (lag_s + lead_s) / np.maximum(count, 1.0)
    alpha = ca_cfar_alpha(np.maximum(count, 1.0), pfa)
    return noise, alpha


# A noiseless (all-zero) spectrum has noise 0, and FFT round-off (~1e-32 of the strongest bin) must
# never pass as a target: detections need positive noise and power above this fraction of the ramp's
# strongest cell (a 200 dB dynamic-range floor).
_FLOOR = 1e-20

# Candidate pairs per spectrum cell up to which the side-lobe test runs on candidate pairs only;
# past it (a spectrum full of local maxima above threshold) the dense loop over distances is cheaper.
_SPARSE_PAIRS_PER_CELL = 8


def _drop_sidelobes(p2: np.ndarray, cand: np.ndarray, env: np.ndarray, null: int, max_dist: int,
                    zero_pad: int, margin: float) -> np.ndarray:
    """``cand`` without the local maxima lying below another candidate's worst-case leakage."""
    rows, idx = np.nonzero(cand)
    out = np.zeros_like(cand)
    keep = _not_sidelobes(p2, rows, idx, env, null, max_dist, zero_pad, margin)
    out[rows[keep], idx[keep]] = True
    return out


def _not_sidelobes(p2: np.ndarray, rows: np.ndarray, idx: np.ndarray, env: np.ndarray, null: int, max_dist: int,
                   zero_pad: int, margin: float) -> np.ndarray:
    """Which candidates (``rows``, ``idx``: row-major cells of ``p2``) are not side-lobes of another.

    Only candidates are tested and only candidates leak, so the test runs on the candidate pairs
    of each ramp (a few per ramp) instead of sweeping the whole (ramps x bins) array once per
    distance (~64 passes, the largest per-pixel cost of the frame DSP). Both give the same cells.
    """
    # leakage factor by distance: env at floor(dist / zero_pad) (the larger, conservative value)
    dist_tab = np.arange(max_dist + 2)
    factor = np.zeros(max_dist + 2)
    e = env[np.minimum(dist_tab // zero_pad, env.size - 1)]
    use = (dist_tab > null) & (dist_tab <= max_dist) & (e * margin >= 1e-12)
    factor[use] = e[use]
    counts = np.bincount(rows, minlength=p2.shape[0]).astype(np.int64)
    if int(np.sum(counts * counts)) > _SPARSE_PAIRS_PER_CELL * p2.size:
        cand_p = np.zeros_like(p2)
        cand_p[rows, idx] = p2[rows, idx]
        leak = np.zeros_like(p2)
        for dist in np.flatnonzero(factor):
            f = factor[dist]
            leak[:, dist:] = np.maximum(leak[:, dist:], cand_p[:, :-dist] * f)
            leak[:, :-dist] = np.maximum(leak[:, :-dist], cand_p[:, dist:] * f)
        return p2[rows, idx] > leak[rows, idx] * margin
    if rows.size == 0:
        return np.ones(0, dtype=bool)
    first = np.cumsum(counts) - counts  # candidates are row-major: each row's are contiguous
    rep = counts[rows]
    tgt = np.repeat(np.arange(rows.size), rep)
    group = np.cumsum(rep) - rep
    src = first[rows[tgt]] + (np.arange(tgt.size) - np.repeat(group, rep))
    dist = np.minimum(np.abs(idx[tgt] - idx[src]), max_dist + 1)
    pc = p2[rows, idx]
    leak = np.maximum.reduceat(pc[src] * factor[dist], group)  # self-pair gives 0
    return pc > leak * margin


@dataclass(frozen=True)
class CfarSettings:
    """The detector's knobs, checked when a detection runs (a DspInputError names a bad one).

    n_ref: reference cells in total (half on each side); n_guard: guard cells on each side.
    window/zero_pad: of the spectrum (for side-lobe, main-lobe and resolution tests).
    iq: spectrum is two-sided and fft-shifted (RangeFFT layout), else one-sided rfft layout.
    bin_range: (first, last) spectrum indices searched (e.g. a range gate).
    dc_guard_bins: bins with |frequency bin| < dc_guard_bins are never reported (default: the
        window's main-lobe half-width, so DC and its lobe are excluded).
    records: the records whose powers were averaged into each cell (incoherent averaging): OS-CFAR's
        threshold factor and noise scale are those of Gamma(records) noise cells (lidard.dsp.detect.os_gamma),
        so ``pfa`` is the rate the detector runs at; CA-CFAR's factor stays the exponential one.
    """

    method: CfarMethod = "os"
    pfa: float = 1e-5
    n_ref: int = 16
    n_guard: int = 2
    os_rank: int | None = None
    max_detections: int = 4
    window: WindowName = "hann"
    zero_pad: int = 1
    iq: bool = False
    bin_range: tuple[int, int] | None = None
    dc_guard_bins: int | None = None
    sidelobe_margin_db: float = 6.0
    harmonic_ratio_db: float = 15.0
    unresolved_factor: float = 1.12
    records: int = 1


_DEFAULT_SETTINGS = CfarSettings()    # OS-CFAR at pfa 1e-5 on a one-sided Hann spectrum


def cfar_detect_with(power: np.ndarray, s: CfarSettings = _DEFAULT_SETTINGS) -> Detections:
    """Detect up to ``s.max_detections`` peaks per ramp in ``power`` (..., n_bins), strongest first,
    with the detector's knobs in ``s`` (their meaning: :class:`CfarSettings`)."""
    p = _checked_power(power, s)
    lead = p.shape[:-1]
    p2 = p.reshape(-1, p.shape[-1])
    n_bins = p2.shape[-1]
    # the compiled OS-CFAR checks the values in its own pass over the spectra; else they are checked here
    kern = jit.kernels(p2.size) if s.method == "os" and n_bins > max(2, s.n_guard + s.n_ref // 2) else None
    if kern is None:
        _check_power_values(p2)
    if n_bins < 3:
        raise DspInputError(f"power has {n_bins} bins; at least 3 are needed")

    rows, cols, nz = _candidates(p2, s, kern)
    k, idx, valid, pk, nz, snr_db = _strongest_cells(p2, rows, cols, nz, s.max_detections)

    # Resolution: the merged lobe of two close targets is wider than one tone's main lobe.
    window, zero_pad = s.window, s.zero_pad
    lobe = _single_tone_width(window, zero_pad)
    width = np.zeros(idx.shape)
    width[valid] = _width_6db(p2, idx, int(np.ceil(4 * lobe)) + 2, rows=np.nonzero(valid)[0], cols=idx[valid])
    unresolved = valid & (width > s.unresolved_factor * lobe)
    harm = _harmonic_ghosts(idx, pk, valid, n_bins=n_bins, iq=s.iq, zero_pad=zero_pad,
                            harmonic_ratio_db=s.harmonic_ratio_db)

    idx = np.where(valid, idx, -1)
    shape = lead + (k,)
    return Detections(
        index=idx.reshape(shape),
        power=pk.reshape(shape),
        noise=nz.reshape(shape),
        snr_db=snr_db.reshape(shape),
        valid=valid.reshape(shape),
        harmonic=harm.reshape(shape),
        unresolved=unresolved.reshape(shape),
        width_bins=width.reshape(shape),
    )


def _checked_power(power: np.ndarray, s: CfarSettings) -> np.ndarray:
    """``power`` as float64 after checking its type and the detector's knobs (a DspInputError names the
    bad one); its values are checked next (:func:`_check_power_values`, or in the compiled pass)."""
    method, window, n_ref, n_guard, max_detections, pfa = s.method, s.window, s.n_ref, s.n_guard, s.max_detections, s.pfa
    p = np.asarray(power)
    if p.dtype.kind not in "fiu" or p.ndim < 1:
        raise DspInputError(f"power must be a real array (..., n_bins), got dtype {p.dtype} ndim {p.ndim}")
    p = p.astype(np.float64, copy=False)
    if method not in CFAR_METHODS:
        raise DspInputError(f"method={method!r} is not a CFAR method; choose one of {CFAR_METHODS}")
    check_window_name(window)
    if n_ref < 2 or n_ref % 2:
        raise DspInputError(f"n_ref={n_ref} must be an even number >= 2 (half on each side)")
    if n_guard < 0:
        raise DspInputError(f"n_guard={n_guard} must be >= 0")
    if max_detections < 1:
        raise DspInputError(f"max_detections={max_detections} must be >= 1")
    _check_pfa(pfa)
    _check_records(s.records)
    return p


def _check_power_values(p: np.ndarray) -> None:
    """A DspInputError if ``p`` holds a NaN, an infinite or a negative value."""
    # two reductions instead of two full boolean maps: min is NaN if any cell is, negative if any is;
    # then a finite sum of non-negative cells has no infinite one (a sum that overflows is re-checked)
    low = p.min() if p.size else 0.0
    with np.errstate(over="ignore"):
        total = p.sum()
    if not np.isfinite(low) or (low >= 0 and not np.isfinite(total) and not np.all(np.isfinite(p))):
        raise DspInputError("power contains NaN or infinite values")
    if low < 0:
        raise DspInputError("power contains negative values; pass |X|^2")


def _candidates(p2: np.ndarray, s: CfarSettings,
                kern: SimpleNamespace | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local maxima above the CFAR threshold that are not side-lobes, the DC lobe or outside the gate:
    (rows, bins, noise) of each, row-major (a few per ramp: the detector never builds a dense map).
    ``kern``: the compiled kernels for OS-CFAR (:mod:`lidard.dsp.spectrum.jit`), or None (numpy)."""
    method, n_ref_side, n_guard, pfa, os_rank = s.method, s.n_ref // 2, s.n_guard, s.pfa, s.os_rank
    window, zero_pad, iq, bin_range, dc_guard_bins = s.window, s.zero_pad, s.iq, s.bin_range, s.dc_guard_bins
    sidelobe_margin_db = s.sidelobe_margin_db
    n_bins = p2.shape[-1]
    if method == "ca":
        floor = _FLOOR * p2.max(axis=-1)
        noise, alpha = _noise_ca(p2, n_ref_side, n_guard, pfa)
        cand = p2 > alpha * noise
        cand &= noise > 0
        cand &= p2 > floor[:, None]
        # local maxima (beyond either edge is -inf), compared in place: no shifted copies of p2
        cand[:, 1:] &= p2[:, 1:] >= p2[:, :-1]
        cand[:, :-1] &= p2[:, :-1] > p2[:, 1:]
        r, c = np.nonzero(cand)
        nz = noise[r, c]
    else:   # OS: only the local maxima that may pass were given the exact statistic (os_cfar)
        found = _os_detected(p2, n_ref_side, n_guard, pfa, os_rank, _FLOOR, kern, s.records)
        if found is None:   # the compiled pass met a NaN, infinite or negative value: name it
            _check_power_values(p2)
            raise DspInputError("power holds a value the compiled CFAR pass refused")
        r, c, nz = found

    # the leakage of the window the spectrum was taken with: its DTFT repeats every n_samples bins, so a
    # shorter stand-in (64 samples) put a main lobe back at 60-64 bins from every peak and took a
    # surface there for a side-lobe of a stronger one. The screen reads LEAKAGE_REACH_BINS out at most:
    # a window of four times that has no periodic copy within reach, and its lobes are the longer
    # ramp's (the exact length is kept below that; the envelope's cost grows with it)
    n_samples = (n_bins if iq else 2 * (n_bins - 1)) // max(int(zero_pad), 1)
    info = window_info(window, min(max(n_samples, 8), 4 * LEAKAGE_REACH_BINS))
    env = info.leakage_envelope
    null = int(np.ceil(info.first_null_bins * zero_pad))
    margin = 10 ** (sidelobe_margin_db / 10.0)
    # Side-lobes: leakage of every above-threshold peak (DC included) into farther bins.
    max_dist = min(n_bins - 1, (env.size - 1) * zero_pad)
    ok = _not_sidelobes(p2, r, c, env, null, max_dist, zero_pad, margin)

    # The DC lobe (offsets, constant ramps, balanced-detector residue) is not a target.
    dc_guard = null if dc_guard_bins is None else int(dc_guard_bins)
    keep = np.ones(n_bins, dtype=bool)
    dc_index = n_bins // 2 if iq else 0
    keep[max(dc_index - dc_guard + 1, 0) : dc_index + dc_guard] = False
    if bin_range is not None:
        lo, hi = bin_range
        in_range = np.zeros(n_bins, dtype=bool)
        in_range[max(lo, 0) : min(hi, n_bins - 1) + 1] = True
        keep &= in_range
    ok &= keep[c]
    return r[ok], c[ok], nz[ok]
