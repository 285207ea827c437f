"""Signed velocity with one photodiode and no speed prior: the three-segment chirp (§2.1.2).

A period is an up ramp, a down ramp and a constant-frequency (CW) segment. With the range beat
f_R = 2 kappa R / c and the return's Doppler shift f_D (``sim_devices``' convention f_D = -2 v / lambda,
v > 0 receding), a real (single-photodiode) receiver sees only magnitudes:

    up: |f_R - f_D|        down: |f_R + f_D|        CW: |f_D|

Write hi = max(f_up, f_dn), lo = min(f_up, f_dn). Two regimes give the same ramp pair with f_R and
|f_D| swapped (docs/physics.md, "Three-segment chirp"):

* not folded (|f_D| < f_R): f_R = (hi + lo) / 2, |f_D| = (hi - lo) / 2;
* folded (|f_D| > f_R):     f_R = (hi - lo) / 2, |f_D| = (hi + lo) / 2;

in both f_R = hi - |f_D| and sign(f_D) = sign(f_dn - f_up). The CW beat |f_D| says which regime holds.
Range and velocity are then taken from the two ramps (v = -lambda f_D / 2): the CW segment's frequency
is held, not linearized, so its beat also carries the laser's thermal relaxation times the round trip
(|f_D - rho f_R|, ``RHO_MAX``); it only has to tell the two regimes apart, whose |f_D| differ by lo.

Evidence, not peaks: the relaxation spreads a far return's CW beat over many bins, where a CFAR would
miss it. For each (up, down) pair each regime predicts the band its CW beat occupies (the measured
drift's, or a RHO_MAX spread around |f_D|); the band's peak, over the CW spectrum's noise, is the line's
noise-normalised power. A regime is possible when that line is detected at the per-ramp level q that
sets the false-point rate (:mod:`lidard.dsp.ranging.points`: the chi-square(2L) law of a cell averaged
over L records), and of two possible regimes the one whose line is stronger is taken (their likelihood
ratio: both predict the same ramp lines, only the CW line differs).

Peaks near DC: the CFAR of the ramps and this search both leave out the DC bin and its window lobe.
A regime predicting |f_D| inside that guard (|v| within a few velocity resolutions) expects no CW beat
and needs none: the not-folded regime, the sign irrelevant. Near |f_D| = f_R one ramp beat sits near DC
and the two regimes predict nearly the same |f_D|: such pairs are ambiguous. With the linearization's
measured drift of the held segment (``FrameDsp.hold_profile``) :mod:`.cwhold` dechirps their CW beat
and ranges them from R = c (hi - f_cw) / (2 kappa) (lone ramp peaks whose partner sits at DC too);
without it they are reported present but not valid.

Several returns: every (up i, down j) pair whose regime is possible is a hypothesis, scored by the
likelihood of its two ramp lines (:mod:`lidard.dsp.ranging.assign`), and the set of pairs of largest
total likelihood is taken (the least motion among equally good sets). Pure numpy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .cwhold import CW_GUARD_BINS, HoldProfile, PairSlots, resolve_boundary
from ..detect.gate import aliased, in_gate, point_flags
from ..spectrum.rangefft import C_M_PER_S, RangeFFT, check_samples
from ..spectrum.scratch import scratch
from .assign import best_matching, line_snr, pair_loglik, tie_llr
from .order import chi2_isf
from .order import median_last as _median_last

#: the held segment's frequency still relaxes (the DFB's thermal terms, ~20 us): over the CW window its
#: slope is taken to lie within RHO_MAX x the ramps' rate (the default DFB after the skip: -9 % .. -1 %,
#: docs/physics.md), so a return's CW beat is spread over |f_D - rho f_R|, |rho| <= RHO_MAX
RHO_MAX = 0.12
#: the CW segment starts this far in: the fastest part of the relaxation is skipped
CW_SKIP_FRACTION = 0.25
#: with the drift measured and taken out (lidard.dsp.ranging.cwhold) only the hold's first 1.6 us are
#: skipped (the AWG's settling into the hold): a longer window, a finer |f_D| (~T^-1.5)
DECHIRP_SKIP_FRACTION = 0.02




def _range_max_table(p: np.ndarray, top_level: int | None = None,
                     levels: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Sparse table: level k holds the max of p over [i, i + 2**k) for every i (range-max queries);
    levels up to ``top_level`` (default: all); ``levels``: the first levels already built (extended
    in place, not rebuilt)."""
    levels = [p] if levels is None else levels
    while 2 ** len(levels) <= p.shape[-1] and (top_level is None or len(levels) <= top_level):
        prev, w = levels[-1], 2 ** (len(levels) - 1)
        levels.append(np.maximum(prev[..., :-w], prev[..., w:]))
    return levels


class _RangeMax:
    """The sparse table of one CW spectrum, built once for every band query and only as deep as the
    widest band asks (six full tables per batch were a third of the three-segment DSP)."""

    def __init__(self, p: np.ndarray):
        self.p = p
        self.levels = [p]

    def __getitem__(self, level: int) -> np.ndarray:
        if level >= len(self.levels):
            _range_max_table(self.p, level, self.levels)     # the levels asked for so far stay
        return self.levels[level]


def cw_band_power(p_cw: np.ndarray, df_hz: float, centre_hz: np.ndarray, half_hz: np.ndarray,
                  guard_bins: int, table: _RangeMax | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Peak power of ``p_cw`` (n, n_bins) over [centre - half, centre + half] per row and candidate
    (n, T), bins below ``guard_bins`` (DC and its window lobe) left out; and whether the band lies
    wholly inside that guard (no CW beat can be seen there). The peak, not the mean: a sharp CW beat
    must not be diluted by a wide band."""
    n_bins = p_cw.shape[-1]
    lo = np.clip(np.floor((centre_hz - half_hz) / df_hz).astype(np.int64), guard_bins, n_bins)
    hi = np.clip(np.ceil((centre_hz + half_hz) / df_hz).astype(np.int64) + 1, guard_bins, n_bins)
    width = hi - lo
    table = _RangeMax(p_cw) if table is None else table
    k = np.floor(np.log2(np.maximum(width, 1))).astype(np.int64)
    rows = np.broadcast_to(np.arange(p_cw.shape[0])[:, None], lo.shape)
    peak = np.zeros(lo.shape)
    for level in np.unique(k[width > 0]):
        m = (k == level) & (width > 0)
        t = table[level]
        peak[m] = np.maximum(t[rows[m], lo[m]], t[rows[m], hi[m] - 2 ** level])
    return peak, width <= 0


def cw_line_threshold(cw_pfa: float, records: int, cells: ArrayLike = 1) -> np.ndarray:
    """The noise-normalised power the peak of ``cells`` CW cells, each averaged over ``records`` records,
    passes with probability ``cw_pfa`` in noise alone (each cell at cw_pfa / cells: chi-square with 2L
    degrees of freedom, over 2L)."""
    w, inv = np.unique(np.maximum(cells, 1), return_inverse=True)   # a few widths: one quantile each
    return (chi2_isf(cw_pfa / w, 2.0 * records) / (2.0 * records))[inv].reshape(np.shape(cells))


def cw_noise(p_cw: np.ndarray, records: int) -> np.ndarray:
    """The CW spectrum's mean noise power per cell (n,): its median over the median of a chi-square(2L)
    / 2L cell (ln 2 for one record)."""
    return _median_last(p_cw) / (float(chi2_isf(0.5, 2.0 * records)) / (2.0 * records))


def _regime_line(table: _RangeMax, df_hz: float, f_r: np.ndarray, d_abs: np.ndarray, noise: np.ndarray,
                 band: tuple[np.ndarray, np.ndarray] | None, s: PairingSettings) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate: (the noise-normalised peak power of the CW band the regime predicts, whether it
    is a line at ``cw_pfa`` over the band's cells). A regime that predicts |f_D| inside the CW's DC
    guard: (+inf, True), no beat can be seen there and none is needed. ``band``: (centre, half width)
    of the CW beat predicted from the measured drift (:func:`drift_band`), searched with 4 bins of
    slack; None: a RHO_MAX spread around |f_D|. ``s``: the DC guard, the records, ``cw_pfa``."""
    guard_bins, guard_hz, records, cw_pfa = s.guard_bins, s.guard_bins * df_hz, s.records, s.cw_pfa
    p_cw = table.p
    n = p_cw.shape[0]
    centre, half = (d_abs, RHO_MAX * f_r + 2 * df_hz) if band is None else (band[0], band[1] + 4 * df_hz)
    centre, half = centre.reshape(n, -1), half.reshape(n, -1)
    pw, _ = cw_band_power(p_cw, df_hz, centre, half, guard_bins, table)
    x = pw / noise
    cells = np.ceil(2 * half / df_hz) + 1
    line = x >= cw_line_threshold(cw_pfa, records, cells)
    guard = d_abs.reshape(n, -1) < guard_hz
    return np.where(guard, np.inf, x).reshape(f_r.shape), (line | guard).reshape(f_r.shape)


def drift_band(f_r: np.ndarray, f_d: np.ndarray, rho: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half width) of |f_R rho(t) - f_D| over the CW window: the band a return's CW beat
    occupies when the held segment's drift rate, relative to the ramps', spans ``rho`` = (lo, hi)
    (measured: lidard.dsp.ranging.cwhold; f_D signed, the bench's convention)."""
    e1, e2 = f_r * rho[0] - f_d, f_r * rho[1] - f_d
    top = np.maximum(np.abs(e1), np.abs(e2))
    bottom = np.where(e1 * e2 > 0, np.minimum(np.abs(e1), np.abs(e2)), 0.0)
    return 0.5 * (top + bottom), 0.5 * (top - bottom)


@dataclass(frozen=True)
class PairingSettings:
    """What the three-segment pairing of one frame holds fixed: the ramps' chirp rate (Hz/s) and the
    wavelength (m), the CW spectrum's DC guard (bins), the slots per pixel (``max_targets``), the records
    the CW spectrum averages, the false-alarm rate of a CW line (``cw_pfa``) and the likelihood level
    under which two assignments tie (``tie_level``, :func:`lidard.dsp.ranging.assign.tie_llr`)."""

    chirp_rate_hz_per_s: float
    wavelength_m: float
    guard_bins: int
    max_targets: int
    records: int = 1
    cw_pfa: float = 1e-6
    tie_level: float = 1e-3


def score_pairs(fu: np.ndarray, fd: np.ndarray, vu: np.ndarray, vd: np.ndarray, p_cw: np.ndarray, df_hz: float,
                s: PairingSettings, *,
                rho: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (up i, down j) pair of every row: (possible (n, K, K), folded, f_range, f_dopp (signed),
    ambiguous).

    possible: the pair's regime predicts a CW line that is there (detected at ``cw_pfa`` over its band's
    cells, the CW spectrum averaged over ``records`` records) or one inside the DC guard; folded: the folded regime's
    line is the stronger; ambiguous: both regimes' bands overlap (|f_D| ~ f_R within the CW spread),
    which holds is not known. ``rho``: the measured drift rate's range over the CW window (relative to
    the ramps'): each regime's band is then where its beat must lie, not a spread allowed around |f_D|."""
    a, b = fu[:, :, None], fd[:, None, :]
    hi, lo = np.maximum(a, b), np.minimum(a, b)
    sign = np.where(b > a, 1.0, -1.0)            # sign(f_dn - f_up) = sign(f_D), both regimes
    noise = np.maximum(cw_noise(p_cw, s.records), 1e-300)[:, None]
    regimes = ((0.5 * (hi + lo), 0.5 * (hi - lo)), (0.5 * (hi - lo), 0.5 * (hi + lo)))   # not folded, folded
    bands: list[Any] = [None, None] if rho is None else [drift_band(f_r, sign * d, rho) for f_r, d in regimes]
    table = _RangeMax(p_cw)                      # one table for both regimes
    (x_n, l_n), (x_f, l_f) = (_regime_line(table, df_hz, f_r, d, noise, band, s)
                              for (f_r, d), band in zip(regimes, bands))
    folded = l_f & (~l_n | (x_f > x_n))
    f_r = np.where(folded, regimes[1][0], regimes[0][0])
    d_abs = np.where(folded, regimes[1][1], regimes[0][1])
    # which regime holds is unknown when the two predictions of |f_D| (lo apart) lie within half the CW
    # spread of each other (with the measured drift: when the two bands overlap)
    if rho is None:
        close = lo < 0.5 * RHO_MAX * 0.5 * (hi + lo) + 2 * df_hz
    else:
        (c_n, h_n), (c_f, h_f) = bands
        close = np.abs(c_n - c_f) < h_n + h_f + 4 * df_hz
    ambiguous = close & np.isfinite(x_n)
    possible = vu[:, :, None] & vd[:, None, :] & (l_n | l_f)
    return possible, folded, f_r, sign * d_abs, ambiguous


def pair_three(ramp_hz: Sequence[ArrayLike], masks: Sequence[ArrayLike], p_cw: np.ndarray, df_hz: float,
               settings: PairingSettings, *, rho: tuple[float, float] | None = None,
               snr: Sequence[np.ndarray] | None = None) -> PairSlots:
    """The assignment of up/down pairs per row of largest total likelihood (module doc).

    Inputs (up, down) ramp magnitudes (Hz) and (up, down) masks, (n, K) each, the CW power spectrum
    (n, n_bins) with bin spacing ``df_hz``; ``snr``: the (up, down) noise-normalised line powers (n, K)
    (None: all alike, the least motion decides). Returns per row and slot (n, max_targets): range_m, velocity_mps
    (positive receding), valid, present (valid, or a pair whose regime is ambiguous: drawn, flagged),
    up and down index.
    """
    fu, fd = (np.abs(np.asarray(f, dtype=np.float64)) for f in ramp_hz)
    vu, vd = (np.asarray(v, dtype=bool) for v in masks)
    chirp_rate_hz_per_s, wavelength_m = settings.chirp_rate_hz_per_s, settings.wavelength_m
    max_targets, records, tie_level = settings.max_targets, settings.records, settings.tie_level
    n, ku = fu.shape
    kd = fd.shape[1]
    ok_pair, _folded, f_r, f_d, amb = score_pairs(fu, fd, vu, vd, p_cw, df_hz, settings, rho=rho)
    loglik = np.ones((n, ku, kd)) if snr is None else pair_loglik(snr[0], snr[1], records)
    match = best_matching(np.where(ok_pair, loglik, -np.inf), np.abs(f_d), tie_llr(tie_level))
    out = {k: np.zeros((n, max_targets)) for k in ("range_m", "velocity_mps")}
    valid = np.zeros((n, max_targets), dtype=bool)
    present = np.zeros((n, max_targets), dtype=bool)
    iu = np.full((n, max_targets), -1, dtype=np.int64)
    idn = np.full((n, max_targets), -1, dtype=np.int64)
    # the pairs into the first slots, strongest evidence first
    order = np.argsort(-np.where(match >= 0, np.take_along_axis(loglik, np.maximum(match, 0)[..., None],
                                                                axis=2)[..., 0], -np.inf), axis=1, kind="stable")
    for s in range(min(max_targets, ku)):
        i = order[:, s]
        j = match[np.arange(n), i]
        r = np.flatnonzero(j >= 0)
        i, j = i[r], j[r]
        out["range_m"][r, s] = C_M_PER_S * f_r[r, i, j] / (2.0 * chirp_rate_hz_per_s)
        out["velocity_mps"][r, s] = -wavelength_m * f_d[r, i, j] / 2.0
        present[r, s] = True
        valid[r, s] = ~amb[r, i, j]
        iu[r, s], idn[r, s] = i, j
    return out["range_m"], out["velocity_mps"], valid, present, iu, idn


# -- the frame DSP's three-segment stage (lidard.dsp.frame.FrameDsp with cw_samples > 0) --------------
def _smooth_at_most(n: int) -> int:
    """The largest even 2-3-5-smooth integer <= n: an FFT of that size is fast (a size with a large
    prime factor, 14,624 = 32 x 457 at a 100 m gate, took ~10x longer)."""
    for m in range(n & ~1, 1, -2):
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
    return 2


def cw_window(dsp: Any, skip_fraction: float = CW_SKIP_FRACTION) -> tuple[int, int]:
    """(first sample, samples used) of the CW segment in a record (after the two ramps): at least the
    first ``skip_fraction`` skipped, an FFT-friendly length ending with the record."""
    n = _smooth_at_most(dsp.cw_samples - int(dsp.cw_samples * skip_fraction))
    return 2 * dsp.ramp_samples + dsp.cw_samples - n, n


def drift_rho(dsp: Any, profile: HoldProfile) -> tuple[float, float]:
    """The measured drift rate's range over the CW window, relative to the ramps' chirp rate (1st to
    99th percentile: the profile's Hilbert edge at the hold's end is not the laser)."""
    a, n = cw_window(dsp)
    t = (a + np.arange(n)) / dsp.fs_hz
    rho = np.gradient(profile.at(t), t) / dsp.chirp_rate_hz_per_s
    lo, hi = np.percentile(rho, [1.0, 99.0])
    return float(lo), float(hi)


def cw_front_end(dsp: Any, x: np.ndarray, lsb_v: float) -> tuple[np.ndarray, float]:
    """The CW segment's power spectrum (n_pix, n_bins), averaged over the pixel's records, and its
    bin spacing (Hz)."""
    a, n = cw_window(dsp)
    rf = _cw_fft(n, dsp.fs_hz, dsp.chirp_rate_hz_per_s, dsp.window)
    seg = x[..., a:a + n]
    volts = np.multiply(seg, lsb_v, dtype=np.float64)     # codes -> volts in one pass (astype, then scale)
    if seg.dtype.kind not in "iu":      # integer codes are finite: no NaN/inf pass over them
        volts = check_samples(volts, n)
    shape = rf.spectrum_shape(volts.shape[:-1])
    p = scratch("threeseg.cw_power", shape, np.float64)
    rf.spectrum_of(volts, scratch("threeseg.cw_spec", shape, np.complex128), power_out=p)
    return p.mean(axis=1), rf.delta_f


@lru_cache(maxsize=8)
def _cw_fft(n: int, fs_hz: float, chirp_rate_hz_per_s: float, window: str) -> RangeFFT:
    """The CW segment's RangeFFT (its window built once per geometry, not on every batch)."""
    return RangeFFT(n, fs_hz, chirp_rate_hz_per_s, window=window)  # type: ignore[arg-type]


def pair_frame_three(dsp: Any, out_f: list[Any], out_det: list[Any], cw: tuple[np.ndarray, float],
                     x: np.ndarray) -> dict[str, Any]:
    """The FrameResult fields (as a dict) of a three-segment frame; ``x`` the batch's records (the
    CW segments the boundary's dechirp reads)."""
    (fu, fd), (du, dd) = out_f, out_det
    p_cw, df = cw
    lead = fu.shape[:-1]
    k = fu.shape[-1]
    flat = [np.abs(a).reshape(-1, a.shape[-1]) for a in (fu, fd)]
    vflat = [m.reshape(-1, m.shape[-1]) for m in (du.valid, dd.valid)]
    profile = dsp.hold
    (flat_u, flat_d), (valid_u, valid_d) = flat, vflat
    pairing = PairingSettings(chirp_rate_hz_per_s=dsp.chirp_rate_hz_per_s, wavelength_m=dsp.wavelength_m,
                              guard_bins=CW_GUARD_BINS, max_targets=k, records=x.shape[1], cw_pfa=dsp.ramp_pfa,
                              tie_level=dsp.order_level)
    rng, vel, ok, seen, iu, idn = pair_three((flat_u, flat_d), (valid_u, valid_d), p_cw.reshape(-1, p_cw.shape[-1]),
                                             df, pairing, rho=dsp.drift_rho,
                                             snr=[a.reshape(-1, k) for a in line_snr(du, dd)])
    if profile is not None:    # where the regimes meet, |f_D| from the dechirped CW segment (lidard.dsp.ranging.cwhold)
        resolve_boundary(dsp, x, profile, flat, vflat,
                         (rng, vel, ok, seen, iu, idn), ramp_df_hz=dsp.rfft.delta_f,
                         cw_window=cw_window(dsp, DECHIRP_SKIP_FRACTION))

    def pick(field_up: np.ndarray, field_dn: np.ndarray) -> np.ndarray:
        a = np.take_along_axis(field_up.reshape(-1, k), np.maximum(iu, 0), axis=1)
        b = np.take_along_axis(field_dn.reshape(-1, k), np.maximum(idn, 0), axis=1)
        return np.where(iu >= 0, a, b)

    harmonic = pick(du.harmonic, dd.harmonic).astype(bool)
    # either ramp's peak not explained by the fitted tones flags the point
    unres = ((np.take_along_axis(du.unresolved.reshape(-1, k), np.maximum(iu, 0), axis=1) & (iu >= 0))
             | (np.take_along_axis(dd.unresolved.reshape(-1, k), np.maximum(idn, 0), axis=1) & (idn >= 0)))
    intensity = 2.0 * np.sqrt(pick(du.power, dd.power))
    # no stronger than what the decimation filter lets through from beyond the gate (lidard.dsp.detect.gate)
    leak = seen & aliased(intensity, dsp.alias_ceiling_v)
    flagged = harmonic | unres | leak
    present = seen & in_gate(rng, dsp.min_range_m, dsp.max_range_m)
    shape = lead + (k,)
    flags = point_flags(unresolved=unres, leak=leak, harmonic=harmonic, unpaired=~ok)
    return dict(present=present.reshape(shape), valid=(present & ok & ~flagged).reshape(shape),
                range_m=rng.reshape(shape), velocity_mps=vel.reshape(shape),
                snr_db=pick(du.snr_db, dd.snr_db).reshape(shape), intensity_v=intensity.reshape(shape),
                flags=flags.reshape(shape))
