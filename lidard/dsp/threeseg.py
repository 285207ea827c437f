"""Signed velocity with one photodiode and no speed prior: the three-segment chirp (issue 14; §2.1.2).

A period is an up ramp, a down ramp and a constant-frequency (CW) segment. With the range beat
f_R = 2 kappa R / c and the return's Doppler shift f_D (``sim_devices``' convention f_D = -2 v / lambda,
v > 0 receding), a real (single-photodiode) receiver sees only magnitudes:

    up: |f_R - f_D|        down: |f_R + f_D|        CW: |f_D|

Write hi = max(f_up, f_dn), lo = min(f_up, f_dn). Two regimes give the same ramp pair with f_R and
|f_D| swapped (docs/physics.md, "Three-segment chirp"):

* not folded (|f_D| < f_R): f_R = (hi + lo) / 2, |f_D| = (hi - lo) / 2;
* folded (|f_D| > f_R):     f_R = (hi - lo) / 2, |f_D| = (hi + lo) / 2;

in both f_R = hi - |f_D| and sign(f_D) = sign(f_dn - f_up). The CW beat |f_D| says which regime holds:
the hypothesis whose |f_D| is nearer the CW peak wins. Range and velocity are then taken from the two
ramps (v = -lambda f_D / 2): the CW segment's frequency is held, not linearized, so its beat also
carries the laser's thermal relaxation times the round trip; it only has to tell the two regimes
apart, which differ by lo in |f_D|.

Peaks near DC: the CFAR excludes the DC bin and its window lobe. No CW peak means |f_D| below the
CW's first bins (|v| under a few velocity resolutions): the not-folded regime, and the sign is
irrelevant. A missing ramp peak means that ramp's beat |f_R -+ f_D| sits near DC (|f_D| ~ f_R): then
f_R = hi - f_CW (the formula of the issue) and |f_D| = f_CW, the sign from which ramp is missing.

Pairing across the three spectra with several returns: every triple (up i | none, down j | none,
CW c | none) is scored in both regimes by how far the CW peak lies from the regime's |f_D| (a missing
CW peak scores how far |f_D| lies above the CW's DC guard), a missing ramp costs one tolerance; the
cheapest triples within ``tol_hz`` are taken greedily, each peak used once (after ``velocity``'s
up/down matcher). Pure numpy.
"""

from __future__ import annotations

import itertools

import numpy as np

from .chain import detect_and_refine
from .rangefft import C_M_PER_S, RangeFFT


def _triples(k_up: int, k_dn: int, k_cw: int) -> np.ndarray:
    """(n_triples, 3) peak indices, -1 = none; at least one ramp present."""
    out = [t for t in itertools.product(range(-1, k_up), range(-1, k_dn), range(-1, k_cw))
           if t[0] >= 0 or t[1] >= 0]
    return np.array(out, dtype=np.int64)


def _take(f: np.ndarray, v: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row and triple: the peak frequency (0 where none) and whether it exists."""
    ok = (idx >= 0)[None, :] & np.take_along_axis(v, np.maximum(idx, 0)[None, :].repeat(len(v), 0), axis=1)
    fv = np.take_along_axis(f, np.maximum(idx, 0)[None, :].repeat(len(f), 0), axis=1)
    return np.where(ok, fv, 0.0), ok


def score_triples(fu, fd, fc, vu, vd, vc, *, tol_hz: float, cw_dc_hz: float):
    """Every candidate triple of every row: (triples (T, 3), cost (n, T), f_range (n, T), f_dopp (n, T)).

    f_dopp is the signed Doppler shift f_D; cost is inf for a triple whose peaks are absent.
    """
    t = _triples(fu.shape[-1], fd.shape[-1], fc.shape[-1])
    a, has_a = _take(fu, vu, t[:, 0])
    b, has_b = _take(fd, vd, t[:, 1])
    c, has_c = _take(fc, vc, t[:, 2])
    exists = (has_a | (t[:, 0] < 0)[None, :]) & (has_b | (t[:, 1] < 0)[None, :]) & (has_c | (t[:, 2] < 0)[None, :])
    hi, lo = np.maximum(a, b), np.minimum(a, b)
    both = has_a & has_b
    sign = np.where(b > a, 1.0, -1.0)          # sign(f_dn - f_up) = sign(f_D), both regimes

    def cw_cost(d_abs):
        return np.where(has_c, np.abs(c - d_abs), np.maximum(d_abs - cw_dc_hz, 0.0))

    cost_n, cost_f = cw_cost(0.5 * (hi - lo)), cw_cost(0.5 * (hi + lo))
    folded = cost_f < cost_n
    d_abs = np.where(folded, 0.5 * (hi + lo), 0.5 * (hi - lo))
    f_r = np.where(folded, 0.5 * (hi - lo), 0.5 * (hi + lo))
    cost = np.minimum(cost_n, cost_f)
    # one ramp near DC: |f_D| ~ f_R, both ~ hi / 2; the CW peak splits them (f_R = hi - f_CW)
    one = ~both
    d_abs = np.where(one, c, d_abs)
    f_r = np.where(one, hi - c, f_r)
    cost = np.where(one, np.abs(c - 0.5 * hi) + tol_hz, cost)
    ok = exists & np.where(one, has_c, True)
    return t, np.where(ok, cost, np.inf), f_r, sign * d_abs


def pair_three(fu, fd, fc, vu, vd, vc, *, chirp_rate_hz_per_s: float, wavelength_m: float, tol_hz: float,
               cw_dc_hz: float, max_targets: int):
    """Greedy assignment of (up, down, CW) peak triples per row (see the module doc).

    Inputs (n, K*) magnitudes in Hz and validity masks. Returns per row and target slot (n, max_targets):
    range_m, velocity_mps (positive receding), valid, and the up / down peak index used (-1: none).
    """
    fu, fd, fc = (np.asarray(x, dtype=np.float64) for x in (fu, fd, fc))
    vu, vd, vc = (np.asarray(x, dtype=bool) for x in (vu, vd, vc))
    n = fu.shape[0]
    t, cost, f_r, f_d = score_triples(fu, fd, fc, vu, vd, vc, tol_hz=tol_hz, cw_dc_hz=cw_dc_hz)
    cost = np.where(cost <= tol_hz * 2, cost, np.inf)
    rng, vel = np.zeros((n, max_targets)), np.zeros((n, max_targets))
    valid = np.zeros((n, max_targets), dtype=bool)
    iu = np.full((n, max_targets), -1, dtype=np.int64)
    idn = np.full((n, max_targets), -1, dtype=np.int64)
    rows = np.arange(n)
    for s in range(max_targets):
        k = np.argmin(cost, axis=1)
        good = np.isfinite(cost[rows, k])
        r, kk = rows[good], k[good]
        rng[r, s] = C_M_PER_S * f_r[r, kk] / (2.0 * chirp_rate_hz_per_s)
        vel[r, s] = -wavelength_m * f_d[r, kk] / 2.0
        valid[r, s] = True
        iu[r, s], idn[r, s] = t[kk, 0], t[kk, 1]
        # each peak is used once: drop every triple sharing a peak with the one taken
        for col in range(3):
            used = t[kk, col]
            clash = (t[None, :, col] == used[:, None]) & (used[:, None] >= 0)
            cost[r] = np.where(clash, np.inf, cost[r])
    return rng, vel, valid, iu, idn


# -- the frame DSP's three-segment stage (lidard.dsp.frame.FrameDsp with cw_samples > 0) --------------
#: the CW segment starts this far in: the laser's fast thermal terms (~1 us) settle first
CW_SKIP_FRACTION = 0.1


def cw_window(dsp) -> tuple[int, int]:
    """(first sample, samples used) of the CW segment in a record (after the two ramps)."""
    skip = int(dsp.cw_samples * CW_SKIP_FRACTION)
    n = (dsp.cw_samples - skip) & ~1
    return 2 * dsp.ramp_samples + skip, n


def cw_fft(dsp):
    _, n = cw_window(dsp)
    return RangeFFT(n, dsp.fs_hz, dsp.chirp_rate_hz_per_s, window=dsp.window)


def cw_front_end(dsp, x: np.ndarray, lsb_v: float):
    """Refined CW beat frequencies (n_pix, K) in Hz and the CW detections."""
    a, n = cw_window(dsp)
    rf = cw_fft(dsp)
    seg = x[..., a:a + n].astype(np.float64) * lsb_v
    spec = rf(seg)
    f_hi = 2.0 * dsp.max_speed_mps / dsp.wavelength_m
    hi = min(int(np.ceil(f_hi / rf.delta_f)) + 2, rf.n_fft // 2)
    res = detect_and_refine(spec, lambda idx: (seg, idx, spec), window=dsp.window, estimator=dsp.estimator,
                            average_axis=1, method="os", pfa=dsp.pfa, max_detections=dsp.max_returns,
                            bin_range=(0, hi))
    return res.frac_bins * rf.delta_f, res.detections


def cw_tolerance_hz(dsp) -> tuple[float, float]:
    """(tol_hz, cw_dc_hz): how far a CW peak may lie from a regime's |f_D| (three CW bins), and the
    CW's DC guard (a |f_D| below it gives no CW peak)."""
    df = cw_fft(dsp).delta_f
    return 3.0 * df, 2.0 * df


def pair_frame_three(dsp, out_f: list, out_det: list, cw) -> dict:
    """The FrameResult fields (as a dict) of a three-segment frame."""
    (fu, fd), (du, dd) = out_f, out_det
    fc, dc = cw
    lead = fu.shape[:-1]
    k = fu.shape[-1]
    tol, dc_hz = cw_tolerance_hz(dsp)
    flat = [np.abs(a).reshape(-1, a.shape[-1]) for a in (fu, fd, fc)]
    vflat = [m.reshape(-1, m.shape[-1]) for m in (du.valid, dd.valid, dc.valid)]
    rng, vel, ok, iu, idn = pair_three(*flat, *vflat, chirp_rate_hz_per_s=dsp.chirp_rate_hz_per_s,
                                       wavelength_m=dsp.wavelength_m, tol_hz=tol, cw_dc_hz=dc_hz, max_targets=k)

    def pick(field_up, field_dn):
        a = np.take_along_axis(field_up.reshape(-1, k), np.maximum(iu, 0), axis=1)
        b = np.take_along_axis(field_dn.reshape(-1, k), np.maximum(idn, 0), axis=1)
        return np.where(iu >= 0, a, b)

    flagged = pick(du.harmonic | du.unresolved, dd.harmonic | dd.unresolved).astype(bool)
    in_gate = (rng >= dsp.min_range_m) & (rng <= dsp.max_range_m * 1.05)
    present = ok & in_gate
    shape = lead + (k,)
    return dict(present=present.reshape(shape), valid=(present & ~flagged).reshape(shape),
                range_m=rng.reshape(shape), velocity_mps=vel.reshape(shape),
                snr_db=pick(du.snr_db, dd.snr_db).reshape(shape),
                intensity_v=(2.0 * np.sqrt(pick(du.power, dd.power))).reshape(shape))
