"""Chirp linearization by iterative learning pre-distortion of the laser drive (dissertation §2.2).

Procedure (Fig. 2-3): send a drive period, record the monitor-MZI beat, turn it into the optical
frequency (Hilbert transform, :mod:`lidard.dsp.instfreq`), compare with the *ideal* linear chirp
(target slope excursion / ramp and free offset) over the learning region of each ramp, and update

    u_{k+1} = Q[ u_k + beta F^-1{ E_k(f) / H(f) } ]

with H(f) the drive-to-frequency response fitted each iteration from the drive that was sent and the
frequency that was measured (:func:`fit_fm_response`: a generic bank of first-order low passes, no
laser model), and Q a zero-phase low pass (FFT mask over the periodic drive). ``update="scalar"``
is the plain law of the issue, ``u_k + beta e_k / K`` with K the fitted tuning slope (Hz/V); one K
is right for a DFB's slow response and several times too large for its fast one, and blind to the
thermal lag, so a laser with a large slow tail (dfb_slow_thermal) learns slowly with it. The figure of merit that is reported
(and that Fig. 2-4 plots) is the RMS chirp *nonlinearity*: the residual after removing the best-fit
line over the region of interest (ROI, the middle 80 % of each ramp).

A laser whose slow thermal terms keep it chirping the old way for microseconds after the drive turns
folds the real MZI beat (its Hilbert phase always increases); the fold is found and undone before
learning (:meth:`_Analyzer._unfold`), otherwise the learner pushes the turning point later every
iteration. A step that would take the drive beyond ``max_drive_factor`` times its initial peak, or
beyond ``max_drive_v`` (the AWG's output range, given by the instrument), is never sent.

Model-free: the learner only sees the drive it sends and the MZI samples it gets back, through
``measure(drive_v, n_avg) -> (n_avg, n)``; it never touches a laser model. It needs no sign of the
tuning either: the frequency is estimated in the drive frame (see :mod:`lidard.dsp.instfreq`), in
which the plant gain is positive on both ramps, so ``K`` (returned as ``tuning_hz_per_v``) is the
*magnitude* of the tuning slope; an intensity MZI cannot observe its sign.

Noise handling: laser phase noise makes the MZI phase noisy (Var = 2 pi linewidth tau_m per sample,
worse relative to the signal the shorter the MZI), so ramps are averaged (``n_avg`` records averaged
coherently before the Hilbert transform), the frequency estimate is low-passed at
``meas_cutoff_hz``, and Q keeps the drive from learning what is left. The noise floor of each
measurement is estimated model-free by splitting the averages into two halves. The frequency is
then re-estimated narrow-band (short-time-spectrum ridge as a reference phase, complex low-pass of
the demodulated beat, ``refine=True``): with a long monitor MZI and a broad linewidth
(tau_m ~ tau_c, where averaging shrinks the beat by exp(-pi linewidth tau_m)) the wide-band Hilbert
phase alone is noise. Phase slips (2 pi
steps at low MZI SNR) are counted and reported. A step that makes the error grow is rejected: the
previous best drive is restored and beta halved (back off instead of diverging).

"up" and "down" name the first and second half of the drive period (with
``sim_devices.world.laser.triangle_drive`` the first half is the optical up-chirp).

Pure numpy/scipy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Literal

import numpy as np

from .ilcquad import quadrature_ramp_nu
from .instfreq import (best_fit_residual, check_finite_array, check_positive, fft_filter,
                       lowpass_padded, ramp_frequency)


def hilbert(*args, **kwargs):
    # imported on first use: scipy.signal costs about a second of every command's start-up (issue 18)
    from scipy.signal import hilbert as fn
    return fn(*args, **kwargs)


MeasureFn = Callable[[np.ndarray, int], np.ndarray]

# narrow-band refinement of the MZI phase (see _Analyzer._refine)
_RIDGE_WINDOW_S = 2e-6
_RIDGE_LOWPASS_HZ = 200e3
_REFINE_BANDS_HZ = (1e6, 300e3)
# fold detection (see _Analyzer._unfold): search the outer 10 % of a ramp for a slope below 0.3 gamma
_FOLD_SEARCH = 0.1
_FOLD_SLOPE = 0.3
# the correction across a turning-point gap switches sides within this time (see _to_drive)
_GAP_SWITCH_S = 1e-6
# inverse-response update (see fit_fm_response): a generic first-order basis, log-spaced
_BASIS_TAUS_S = (10e-9, 30e-9, 100e-9, 300e-9, 1e-6, 3e-6, 10e-6, 30e-6, 100e-6, 300e-6, 1e-3, 3e-3)
_BASIS_RIDGE = 1e-2
_BASIS_DECIMATE = 4
_INVERSE_FLOOR = 0.1


@dataclass(frozen=True)
class IlcIteration:
    """One measurement: iteration 0 is the initial drive, k the drive after k updates.

    ``up_rms_hz``/``down_rms_hz``: RMS nonlinearity over the ROI (best-fit line removed);
    ``up_error_hz``/``down_error_hz``: RMS error against the ideal chirp (what is learned);
    ``noise_floor_hz``: estimated measurement-noise contribution to the RMS nonlinearity (NaN if n_avg < 2);
    ``beta``: the learning gain used for the update that *follows* this measurement;
    ``accepted``: False if this drive made the error grow and was rolled back;
    ``averages``: the periods averaged (more when the noise floor stopped learning early).
    """

    index: int
    up_rms_hz: float
    down_rms_hz: float
    up_error_hz: float
    down_error_hz: float
    noise_floor_hz: float
    tuning_hz_per_v: float
    beta: float
    phase_slips: int
    accepted: bool
    averages: int = 0          # periods averaged for this measurement

    def __getitem__(self, key: str):  # allow it["up_rms_hz"] as in the task's dict notation
        return getattr(self, key)


@dataclass(frozen=True)
class IlcResult:
    drive_v: np.ndarray                    # best drive found (one period at fs_drive_hz)
    iterations: list[IlcIteration]
    reduction: dict[str, float]            # initial / best RMS nonlinearity, keys "up", "down"
    converged: bool
    tuning_hz_per_v: float                 # |K| fitted at the best iteration
    best_iteration: int
    phase_slips: int                       # total over all measurements
    stop_reason: str = ""
    meta: dict = field(default_factory=dict)


@dataclass
class _Analysis:
    rms: tuple[float, float]
    err_rms: tuple[float, float]
    noise: float
    tuning: float
    slips: int
    err_drive: np.ndarray                  # error (Hz, drive frame) on the drive grid, tapered
    ramps_nu: list                         # per ramp (t, drive-frame nu) as measured, for the plant fit


class _Analyzer:
    """Everything about turning one averaged MZI record into errors; fixed geometry per run."""

    def __init__(self, *, fs_drive_hz, fs_adc_hz, ramp_s, excursion_hz, mzi_delay_s, roi, learn,
                 meas_cutoff_hz, directions, refine=True):
        self.fs_d, self.fs_a, self.T = fs_drive_hz, fs_adc_hz, ramp_s
        self.tau_m, self.roi, self.learn = mzi_delay_s, roi, learn
        self.slope = excursion_hz / ramp_s
        self.f_beat = self.slope * mzi_delay_s
        self.meas_cutoff = meas_cutoff_hz
        self.directions = directions
        self.refine = refine
        self.n_adc = int(round(2 * ramp_s * fs_adc_hz))
        self.n_drive = int(round(2 * ramp_s * fs_drive_hz))
        self.t_drive = np.arange(self.n_drive) / fs_drive_hz
        # Hilbert transients and turning points: a few beat periods, but never into the learn region
        self.edge_s = min(3.0 / self.f_beat, 0.5 * (1 - learn) * ramp_s)

    def _ramp_nu(self, x_avg: np.ndarray):
        """Band-pass the averaged period, then per ramp: drive-frame nu (low-passed) on its time axis."""
        lo = 0.25 * self.f_beat
        hi = max(4.0 * self.f_beat, 4.0 * self.meas_cutoff)
        xb = fft_filter(x_avg, self.fs_a, lo_hz=lo, hi_hz=min(hi, 0.4 * self.fs_a))
        n_r = self.n_adc // 2
        out = []
        for r in range(2):
            rf = ramp_frequency(xb[r * n_r:(r + 1) * n_r], fs_hz=self.fs_a, mzi_delay_s=self.tau_m,
                                t0_s=r * self.T, direction=self.directions[r], edge_s=self.edge_s,
                                trend_hz=0.5 * self.f_beat)
            t = rf.t_s[rf.valid]
            nu = self._refine(xb[r * n_r:(r + 1) * n_r], rf) if self.refine else rf.nu_hz[rf.valid]
            nu = lowpass_padded(nu, self.fs_a, self.meas_cutoff)
            out.append((t, self._unfold(nu, self.directions[r]), rf.phase_slips))
        return out

    def _refine(self, seg: np.ndarray, rf) -> np.ndarray:
        """Narrow-band re-estimate of one ramp's drive-frame nu (valid samples).

        The Hilbert phase of the averaged beat takes the whole pass band's noise non-linearly. With a
        long MZI and a broad linewidth (tau_m ~ tau_c) averaging shrinks the beat by
        exp(-pi linewidth tau_m) while the residual noise stays broadband, and that phase slips and
        wanders by MHz. Here the local beat frequency is read off the ridge of a short-time spectrum
        (a 2 us window integrates the noise away), integrated to a reference phase, and the beat is
        demodulated by it and low-passed *as a complex phasor* (1 MHz, then 300 kHz) before its angle
        corrects the reference: the noise enters only through that narrow band.
        """
        n = seg.size
        pad = min(n - 1, max(1, int(math.ceil(self.edge_s * self.fs_a))))
        ext = np.concatenate([seg[pad:0:-1], seg, seg[-2:-pad - 2:-1]])
        a = hilbert(ext - ext.mean())[pad:pad + n]
        lw = min(n, max(16, int(round(_RIDGE_WINDOW_S * self.fs_a))))
        hop = max(1, lw // 4)
        nfft = 8 * lw
        frames = np.lib.stride_tricks.sliding_window_view(a, lw)[::hop] * np.hanning(lw)
        sp = np.abs(np.fft.fft(frames, nfft, axis=1))
        sp[:, nfft // 2:] = 0.0                  # positive beat frequencies only
        sp[:, 0] = 0.0
        k = np.argmax(sp, axis=1)
        kk = np.clip(k, 1, nfft - 2)
        rows = np.arange(k.size)
        y0, y1, y2 = (np.log(sp[rows, kk + d] + 1e-300) for d in (-1, 0, 1))
        den = y0 - 2 * y1 + y2
        dk = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
        centers = np.arange(k.size) * hop + 0.5 * (lw - 1)
        f_ridge = np.interp(np.arange(n), centers, (kk + dk) * self.fs_a / nfft)
        f_ridge = lowpass_padded(f_ridge, self.fs_a, _RIDGE_LOWPASS_HZ)
        psi = 2 * np.pi * np.cumsum(f_ridge) / self.fs_a
        for bw in _REFINE_BANDS_HZ:
            z = a * np.exp(-1j * psi)
            psi = psi + np.unwrap(np.arctan2(lowpass_padded(z.imag, self.fs_a, bw),
                                             lowpass_padded(z.real, self.fs_a, bw)))
        return rf.direction * psi[rf.valid] / (2 * np.pi * self.tau_m)

    def _unfold(self, nu: np.ndarray, direction: int) -> np.ndarray:
        """Undo the fold of a real beat where the optical chirp turns *after* the drive does.

        A laser with slow thermal terms keeps chirping the old way for microseconds after the drive
        turns. The real MZI beat cannot show that: its frequency dips to zero at the optical turning
        point and the Hilbert phase, which always increases, folds the wrong-way part over (drive
        frame: ``nu_meas = 2 nu(t_turn) - nu_true`` before the turn). Learning from the folded part
        pushes with the wrong sign and drags the turning point later every iteration. A fold is an
        *interior* minimum of the drive-frame slope near a ramp end, close to zero, with the slope
        rising again towards the end; there the folded part is reflected back.
        """
        slope = direction * np.gradient(nu) * self.fs_a
        n = nu.size
        q = max(2, int(_FOLD_SEARCH * n))
        floor = _FOLD_SLOPE * self.slope
        i = int(np.argmin(slope[:q]))
        if 0 < i and slope[i] < floor and slope[:i].max() > 2 * max(slope[i], 0.0) + 0.05 * self.slope:
            nu = nu.copy()
            nu[:i] = 2 * nu[i] - nu[:i]
        j = n - q + int(np.argmin(slope[n - q:]))
        if j < n - 1 and slope[j] < floor and slope[j + 1:].max() > 2 * max(slope[j], 0.0) + 0.05 * self.slope:
            nu = nu.copy()
            nu[j + 1:] = 2 * nu[j] - nu[j + 1:]
        return nu

    def _roi(self, t: np.ndarray, r: int, frac: float) -> np.ndarray:
        tr = t - r * self.T
        return (tr >= 0.5 * (1 - frac) * self.T) & (tr <= 0.5 * (1 + frac) * self.T)

    def _records_nu(self, y: np.ndarray):
        """Per ramp (t, drive-frame nu, slips) of a set of records: a real fringe is averaged coherently
        then demodulated; a quadrature one (complex I + jQ) is demodulated per record and its phases
        averaged (:mod:`lidard.dsp.ilcquad`)."""
        if np.iscomplexobj(y):
            return quadrature_ramp_nu(y, fs_hz=self.fs_a, ramp_s=self.T, mzi_delay_s=self.tau_m,
                                      edge_s=self.edge_s, directions=self.directions,
                                      meas_cutoff_hz=self.meas_cutoff)
        return self._ramp_nu(y.mean(axis=0))

    def analyse(self, y: np.ndarray, u: np.ndarray) -> _Analysis:
        full = self._records_nu(y)
        noise = float("nan")
        if y.shape[0] >= 2:
            a, b = self._records_nu(y[0::2]), self._records_nu(y[1::2])
            nf = []
            for r in range(2):
                m = self._roi(a[r][0], r, self.roi)
                nf.append(float(np.sqrt(np.mean(best_fit_residual(a[r][0][m], 0.5 * (a[r][1][m] - b[r][1][m])) ** 2))))
            # halves of an odd count are unequal; the mean of both is close enough for a floor
            noise = max(nf)
        rms, err_rms, slips = [], [], 0
        ramps_e = []
        ramps_nu = []
        su = sv = suu = 0.0
        for r, (t, nu, s) in enumerate(full):
            slips += s
            roi = self._roi(t, r, self.roi)
            rms.append(float(np.sqrt(np.mean(best_fit_residual(t[roi], nu[roi]) ** 2))))
            ideal = self.directions[r] * self.slope * (t - t[roi].mean())
            e = ideal - nu
            e -= e[roi].mean()                      # the optical offset is free: only the shape counts
            err_rms.append(float(np.sqrt(np.mean(e[roi] ** 2))))
            # tuning magnitude: regress nu on the drive (periodic interpolation) over the ROI
            ud = np.interp(t[roi], self.t_drive, u, period=2 * self.T)
            uc, vc = ud - ud.mean(), nu[roi] - nu[roi].mean()
            su += float(np.dot(uc, vc))
            suu += float(np.dot(uc, uc))
            ramps_e.append((t, e))
            ramps_nu.append((t, nu))
        tuning = su / suu if suu > 0 else float("nan")
        return _Analysis(rms=(rms[0], rms[1]), err_rms=(err_rms[0], err_rms[1]), noise=noise,
                         tuning=tuning, slips=slips, err_drive=self._to_drive(ramps_e), ramps_nu=ramps_nu)

    def _to_drive(self, ramps: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Error on the drive grid: interpolated over each learning region; across the gaps around
        the turning points (no reliable measurement there) each edge value is held and the two are
        joined by a raised cosine 1 us wide at the drive's turning point (Q limits the step).

        Every drive sample gets a value: a sample that falls on a region's edge, where the masks
        below meet with strict and non-strict comparisons of float times, is interpolated from its
        neighbours. (It used to keep whatever ``np.empty`` left there: garbage that changed with the
        process's allocation history, at times 1e300, which Q spread into a drive of ~100 V.)"""
        period = 2 * self.T
        knots_t, knots_e = [], []
        for r, (t, e) in enumerate(ramps):
            tr = t - r * self.T
            inside = (tr >= 0.5 * (1 - self.learn) * self.T) & (tr <= 0.5 * (1 + self.learn) * self.T)
            knots_t.append(t[inside])
            knots_e.append(e[inside])
        out = np.full(self.n_drive, np.nan)
        td = self.t_drive
        for r in range(2):
            ti, ei = knots_t[r], knots_e[r]
            m = (td >= ti[0]) & (td <= ti[-1])
            out[m] = np.interp(td[m], ti, ei)
            # gap from the end of this learning region to the start of the next (wrapping the period)
            t_a, e_a = ti[-1], ei[-1]
            nt, ne = knots_t[(r + 1) % 2], knots_e[(r + 1) % 2]
            t_b, e_b = nt[0] + (period if r == 1 else 0.0), ne[0]
            tg = np.where(td < ti[-1] - 0.5 * period, td + period, td) if r == 1 else td
            g = (tg > t_a) & (tg < t_b)
            s = (tg[g] - t_a) / (t_b - t_a)
            # hold each side's edge value and switch over within _GAP_SWITCH_S around the drive's
            # turning point: the correction a ramp's start asks for (the pre-emphasis that makes
            # a slow laser turn quickly) is then applied right after the turn, not smeared into
            # the end of the other ramp
            x = np.clip((s - 0.5) * (t_b - t_a) / _GAP_SWITCH_S + 0.5, 0.0, 1.0)
            out[g] = e_a + (e_b - e_a) * 0.5 * (1 - np.cos(np.pi * x))
        hole = np.isnan(out)
        if hole.any():
            out[hole] = np.interp(td[hole], td[~hole], out[~hole], period=period)
        return out


def fit_fm_response(drive_v, ramps_nu, *, fs_drive_hz: float, ramp_s: float, learn: float,
                    floor_hz_per_v: float) -> np.ndarray:
    """Model-free estimate of the FM response H(f) (Hz/V, drive frame) on the drive's rfft grid.

    The measured drive-frame frequency over the learning regions is regressed on the drive passed
    through a fixed, generic bank of first-order low passes (log-spaced 10 ns .. 3 ms, plus the
    direct term) with a free offset per ramp; ridge-regularised least squares. Nothing about the
    laser goes in: only the drive that was sent and what the MZI saw. ``|H|`` is floored at
    ``floor_hz_per_v`` so that dividing by it never blows up where the fit is poor.

    Why: one scalar K is right for the slow part of a DFB's response and 5-10x too large for its fast
    part (the carrier and thermal terms cancel at high frequency), and it ignores the thermal phase
    lag, so fine features learn slowly and a slow tail couples the ramps. Dividing the error by the
    fitted H(f) is the classic inverse-model ILC update.
    """
    u = np.asarray(drive_v, dtype=np.float64)
    n = u.size
    f = np.fft.rfftfreq(n, d=1.0 / fs_drive_hz)
    spec = np.fft.rfft(u)
    resp = [np.ones_like(f, dtype=complex)] + [1.0 / (1.0 + 2j * np.pi * f * tau) for tau in _BASIS_TAUS_S]
    basis = [np.fft.irfft(spec * r, n=n) for r in resp]
    td = np.arange(n) / fs_drive_hz
    rows, ys = [], []
    for r, (t, nu) in enumerate(ramps_nu):
        tr = t - r * ramp_s
        m = (tr >= 0.5 * (1 - learn) * ramp_s) & (tr <= 0.5 * (1 + learn) * ramp_s)
        tm = t[m][::_BASIS_DECIMATE]
        cols = [np.interp(tm, td, b, period=2 * ramp_s) for b in basis]
        cols += [np.full(tm.size, 1.0 if q == r else 0.0) for q in range(len(ramps_nu))]
        rows.append(np.stack(cols, axis=1))
        ys.append(nu[m][::_BASIS_DECIMATE])
    a = np.concatenate(rows)
    y = np.concatenate(ys)
    scale = np.abs(a).max(axis=0)
    scale[scale == 0] = 1.0
    an = a / scale
    gram = an.T @ an
    lam = _BASIS_RIDGE * np.trace(gram) / gram.shape[0]
    g = np.linalg.solve(gram + lam * np.eye(gram.shape[0]), an.T @ y) / scale
    h = sum(gk * rk for gk, rk in zip(g[:len(resp)], resp))
    mag = np.abs(h)
    return np.where(mag < floor_hz_per_v, h / np.maximum(mag, 1e-300) * floor_hz_per_v, h)


def _norm(pair: tuple[float, float]) -> float:
    return math.hypot(pair[0], pair[1])


def _directions(u: np.ndarray) -> tuple[int, int]:
    n = u.size // 2
    d = []
    for seg in (u[:n], u[n:]):
        k = max(1, seg.size // 10)
        step = seg[-k:].mean() - seg[:k].mean()
        if step == 0:
            raise ValueError("drive0_v: a ramp has no net drive change; expected one triangle period")
        d.append(1 if step > 0 else -1)
    if d[0] == d[1]:
        raise ValueError("drive0_v: both halves ramp the same way; expected a triangle (up then down)")
    return d[0], d[1]


def linearize(measure: MeasureFn, drive0_v, *, fs_drive_hz: float, fs_adc_hz: float, ramp_s: float,
              excursion_hz: float, mzi_delay_s: float, beta: float = 0.8, max_iter: int = 14,
              roi: float = 0.8, averages: int = 128, learn: float = 0.92,
              q_cutoff_hz: float = 1.0e6, meas_cutoff_hz: float = 400e3,
              rel_tol: float = 0.02, grow_tol: float = 0.2, min_beta: float = 0.05,
              abs_tol_frac: float = 1e-6, refine: bool = True,
              update: Literal["inverse", "scalar"] = "inverse", max_drive_factor: float = 4.0,
              max_drive_v: float | None = None, max_averages: int | None = None,
              target_frac: float = 4e-6) -> IlcResult:
    """Iteratively pre-distort ``drive0_v`` so that the MZI-measured chirp becomes linear (§2.2).

    ``measure(drive_v, n_avg)`` plays one period of ``drive_v`` (at ``fs_drive_hz``, repeated) and
    returns ``n_avg`` recorded periods of the monitor-MZI beat, shape ``(n_avg, 2 ramp_s fs_adc_hz)``,
    each aligned with the start of the drive period: real (one photodiode), or complex I + jQ for a
    quadrature monitor (``[monitor] quadrature``; phases averaged, see :mod:`lidard.dsp.ilcquad`). Stops when the nonlinearity reaches twice the
    measured noise floor or stops improving by ``rel_tol``; a step whose error grows by more than
    ``grow_tol`` is rolled back and beta halved. Returns the best drive seen.

    Averaging: when the noise floor stops it while the nonlinearity is still above ``target_frac`` of
    the excursion, the same drive is measured again with twice the averages (up to ``max_averages``;
    default: no growth) and learning goes on. A broad-linewidth laser on a long MZI needs this: its
    averaged beat shrinks by exp(-pi linewidth tau_m) while the noise does not, and a narrow laser
    never pays for it. The default target, 4e-6 of the excursion, is what a >= 1000x reduction of a
    ~0.7 % RMS nonlinearity needs (issue 15); the measurement itself is unchanged.
    """
    if not callable(measure):
        raise TypeError("measure must be callable as measure(drive_v, n_avg)")
    u0 = check_finite_array("drive0_v", drive0_v, ndim=(1,)).copy()
    fs_drive_hz = check_positive("fs_drive_hz", fs_drive_hz)
    fs_adc_hz = check_positive("fs_adc_hz", fs_adc_hz)
    ramp_s = check_positive("ramp_s", ramp_s)
    excursion_hz = check_positive("excursion_hz", excursion_hz)
    mzi_delay_s = check_positive("mzi_delay_s", mzi_delay_s)
    check_positive("q_cutoff_hz", q_cutoff_hz)
    check_positive("meas_cutoff_hz", meas_cutoff_hz)
    if not (math.isfinite(beta) and 0 < beta <= 10):
        raise ValueError(f"beta must be in (0, 10], got {beta!r}")
    if not 0 < roi < learn <= 1:
        raise ValueError(f"need 0 < roi < learn <= 1, got roi={roi!r}, learn={learn!r}")
    if int(max_iter) != max_iter or max_iter < 0:
        raise ValueError(f"max_iter must be a non-negative integer, got {max_iter!r}")
    if update not in ("inverse", "scalar"):
        raise ValueError(f"update must be 'inverse' or 'scalar', got {update!r}")
    if not (math.isfinite(max_drive_factor) and max_drive_factor >= 1):
        raise ValueError(f"max_drive_factor must be >= 1, got {max_drive_factor!r}")
    if max_drive_v is not None and not (math.isfinite(max_drive_v) and max_drive_v > 0):
        raise ValueError(f"max_drive_v must be a finite voltage > 0, got {max_drive_v!r}")
    if int(averages) != averages or averages < 1:
        raise ValueError(f"averages must be a positive integer, got {averages!r}")
    max_avg = int(averages) if max_averages is None else max_averages
    if int(max_avg) != max_avg or max_avg < averages:
        raise ValueError(f"max_averages must be an integer >= averages ({averages}), got {max_averages!r}")
    if not (math.isfinite(target_frac) and target_frac >= 0):
        raise ValueError(f"target_frac must be finite and >= 0, got {target_frac!r}")
    n_avg = [int(averages)]                # grows when the noise floor stops learning too early
    n_drive = 2 * ramp_s * fs_drive_hz
    if abs(n_drive - u0.size) > 0.5:
        raise ValueError(f"drive0_v has {u0.size} samples; one period 2 ramp_s fs_drive_hz is {n_drive:g}")
    an = _Analyzer(fs_drive_hz=fs_drive_hz, fs_adc_hz=fs_adc_hz, ramp_s=ramp_s, excursion_hz=excursion_hz,
                   mzi_delay_s=mzi_delay_s, roi=roi, learn=learn, meas_cutoff_hz=meas_cutoff_hz,
                   directions=_directions(u0), refine=bool(refine))
    if an.f_beat * ramp_s < 10:
        raise ValueError(f"MZI beat {an.f_beat:g} Hz gives < 10 fringes per ramp: mzi_delay_s too short")

    def run(u: np.ndarray) -> _Analysis:
        y = np.asarray(measure(u.copy(), n_avg[0]))
        y = y.astype(np.complex128 if np.iscomplexobj(y) else np.float64)
        if y.ndim == 1:
            y = y[None, :]
        if y.ndim != 2 or y.shape[1] != an.n_adc:
            raise ValueError(f"measure returned shape {y.shape}; expected (n_avg, {an.n_adc})")
        check_finite_array("MZI samples from measure", y.view(np.float64))
        return an.analyse(y, u)

    iters: list[IlcIteration] = []
    u = u0
    peak0 = float(np.abs(u0).max())
    if max_drive_v is not None and peak0 > max_drive_v:
        raise ValueError(f"drive0_v peaks at {peak0:.4g} V, beyond max_drive_v = {max_drive_v:.4g} V")
    # the largest |drive| ever sent: relative to the plain drive, and the output stage's range
    cap_v = max_drive_factor * peak0 if max_drive_v is None else min(max_drive_factor * peak0, max_drive_v)
    a = run(u)
    first = a
    cur_u, cur_a = u, a                    # the drive the next update starts from
    best_u, best_a, best_k = u, a, 0
    slips = a.slips
    converged, reason = False, "max_iter reached"
    b = float(beta)
    k = 0
    stalled = 0
    while True:
        accepted = True
        if k > 0:
            # near the floor the error fluctuates with the noise: only growth beyond that is divergence
            floor = 3.0 * a.noise if math.isfinite(a.noise) else 0.0
            if max(a.err_rms) > (1 + grow_tol) * max(cur_a.err_rms) + floor:
                accepted = False           # roll back to the last good drive, learn more gently
                b *= 0.5
            else:
                improvement = 1 - _norm(a.err_rms) / _norm(cur_a.err_rms)
                stalled = stalled + 1 if improvement < rel_tol else 0
                cur_u, cur_a = u, a
                if _norm(a.err_rms) < _norm(best_a.err_rms):
                    best_u, best_a, best_k = u, a, k
        iters.append(IlcIteration(index=k, up_rms_hz=a.rms[0], down_rms_hz=a.rms[1], up_error_hz=a.err_rms[0],
                                  down_error_hz=a.err_rms[1], noise_floor_hz=a.noise, tuning_hz_per_v=a.tuning,
                                  beta=b, phase_slips=a.slips, accepted=accepted, averages=n_avg[0]))
        if k == 0 and max(a.rms) <= abs_tol_frac * excursion_hz:
            converged, reason = True, "already linear: nonlinearity below abs_tol_frac of the excursion"
            break
        if k > 0 and accepted:
            while (math.isfinite(a.noise) and max(a.rms) <= 2.0 * a.noise
                   and max(a.rms) > target_frac * excursion_hz and 2 * n_avg[0] <= max_avg):
                n_avg[0] *= 2                  # the same drive, measured with less noise
                a = run(u)
                slips += a.slips
                cur_a = a
                if _norm(a.err_rms) <= _norm(best_a.err_rms) or best_k == k:
                    best_u, best_a, best_k = u, a, k
                iters[-1] = replace(iters[-1], up_rms_hz=a.rms[0], down_rms_hz=a.rms[1],
                                    up_error_hz=a.err_rms[0], down_error_hz=a.err_rms[1],
                                    noise_floor_hz=a.noise, tuning_hz_per_v=a.tuning, phase_slips=a.slips,
                                    averages=n_avg[0])
            if math.isfinite(a.noise) and max(a.rms) <= 2.0 * a.noise:
                converged, reason = True, "reached the measurement noise floor"
                break
            if max(a.rms) <= abs_tol_frac * excursion_hz:
                converged, reason = True, "nonlinearity below abs_tol_frac of the excursion"
                break
            if stalled >= 2:
                converged, reason = True, "error stopped improving"
                break
        if k >= max_iter:
            break
        if b < min_beta:
            reason = "beta backed off below min_beta"
            break
        K = cur_a.tuning
        if not (math.isfinite(K) and K > 0):
            reason = "tuning slope not measurable"
            break
        k += 1
        if update == "inverse":
            h = fit_fm_response(cur_u, cur_a.ramps_nu, fs_drive_hz=fs_drive_hz, ramp_s=ramp_s, learn=learn,
                                floor_hz_per_v=_INVERSE_FLOOR * K)
            step = np.fft.irfft(np.fft.rfft(cur_a.err_drive) / h, n=cur_u.size)
        else:
            step = cur_a.err_drive / K
        u = fft_filter(cur_u + b * step, fs_drive_hz, hi_hz=q_cutoff_hz)
        if not np.abs(u).max() <= cap_v:
            # a step this large is a broken measurement or fit, never a linearization: do not send it
            b *= 0.5
            iters[-1] = replace(iters[-1], beta=b)
            if b < min_beta:
                reason = "beta backed off below min_beta"
                break
            u = fft_filter(cur_u + b * cur_a.err_drive / K, fs_drive_hz, hi_hz=q_cutoff_hz)
            if not np.abs(u).max() <= cap_v:
                reason = (f"update would exceed {cap_v:.4g} V peak ({max_drive_factor:g} x the initial drive "
                          f"peak{'' if max_drive_v is None else f' or max_drive_v = {max_drive_v:.4g} V'})")
                break
        a = run(u)
        slips += a.slips
    red = {"up": first.rms[0] / best_a.rms[0] if best_a.rms[0] > 0 else math.inf,
           "down": first.rms[1] / best_a.rms[1] if best_a.rms[1] > 0 else math.inf}
    return IlcResult(drive_v=best_u, iterations=iters, reduction=red, converged=converged,
                     tuning_hz_per_v=best_a.tuning, best_iteration=best_k, phase_slips=slips,
                     stop_reason=reason,
                     meta={"meas_cutoff_hz": meas_cutoff_hz, "q_cutoff_hz": q_cutoff_hz, "averages": n_avg[0],
                           "roi": roi, "learn": learn, "mzi_beat_hz": an.f_beat})
