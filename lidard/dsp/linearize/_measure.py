"""ILC measurement: one averaged monitor-MZI record turned into chirp errors (dissertation §2.2, Fig. 2-3).

The measurement half of :mod:`lidard.dsp.linearize.ilc`: band-pass and Hilbert-demodulate each ramp of the
averaged beat into the drive-frame optical frequency (:mod:`lidard.dsp.spectrum.instfreq`), refine it
narrow-band (short-time-spectrum ridge + complex low pass), undo the fold a late optical turning point
leaves in a real beat, and compare with the ideal linear chirp over the region of interest: RMS
nonlinearity, RMS error, the model-free noise floor (two halves of the averages), the tuning magnitude
and the error resampled onto the drive grid for the update (:mod:`lidard.dsp.linearize._update`).

Pure numpy/scipy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from .quadrature import quadrature_ramp_nu
from ..spectrum.instfreq import (
    RampFrequency,
    best_fit_residual,
    check_positive,
    fft_filter,
    hilbert,
    lowpass_padded,
    ramp_frequency,
)

# narrow-band refinement of the MZI phase (see _Analyzer._refine)
_RIDGE_WINDOW_S = 2e-6
_RIDGE_LOWPASS_HZ = 200e3
_REFINE_BANDS_HZ = (1e6, 300e3)
# fold detection (see _Analyzer._unfold): search the outer 10 % of a ramp for a slope below 0.3 gamma
_FOLD_SEARCH = 0.1
_FOLD_SLOPE = 0.3
# the correction across a turning-point gap switches sides within this time (see _to_drive)
_GAP_SWITCH_S = 1e-6


@dataclass(frozen=True)
class ChirpGeometry:
    """The chirp a linearization learns and the monitor that sees it (what :func:`lidard.dsp.linearize.ilc.linearize`
    and :func:`lidard.dsp.linearize.chirpcheck.chirp_residual` share): the drive's sample rate (Hz), the digitizer's
    (Hz), the duration of one ramp (two per drive period, s), the optical excursion of a ramp (Hz) and
    the monitor MZI's delay (s)."""

    fs_drive_hz: float
    fs_adc_hz: float
    ramp_s: float
    excursion_hz: float
    mzi_delay_s: float

    def checked(self) -> ChirpGeometry:
        """The same values as floats; a ValueError names the first that is not positive and finite."""
        return ChirpGeometry(*(check_positive(f.name, getattr(self, f.name)) for f in fields(self)))


@dataclass
class _Analysis:
    rms: tuple[float, float]
    err_rms: tuple[float, float]
    noise: float
    tuning: float
    slips: int
    err_drive: np.ndarray                  # error (Hz, drive frame) on the drive grid, tapered
    ramps_nu: list[Any]                     # per ramp (t, drive-frame nu) as measured, for the plant fit


class _Analyzer:
    """Everything about turning one averaged MZI record into errors; fixed geometry per run."""

    def __init__(self, chirp: ChirpGeometry, *, roi: float, learn: float, meas_cutoff_hz: float,
                 directions: tuple[int, int], refine: bool = True) -> None:
        fs_drive_hz, fs_adc_hz, ramp_s = chirp.fs_drive_hz, chirp.fs_adc_hz, chirp.ramp_s
        excursion_hz, mzi_delay_s = chirp.excursion_hz, chirp.mzi_delay_s
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

    def _ramp_nu(self, x_avg: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, int]]:
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

    def _refine(self, seg: np.ndarray, rf: RampFrequency) -> np.ndarray:
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

    def _records_nu(self, y: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, int]]:
        """Per ramp (t, drive-frame nu, slips) of a set of records: a real fringe is averaged coherently
        then demodulated; a quadrature one (complex I + jQ) is demodulated per record and its phases
        averaged (:mod:`lidard.dsp.linearize.quadrature`)."""
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
        su = suu = 0.0
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

