"""The held segment's frequency drift, measured once and taken out of the CW beat (§2.2).

The three-segment chirp's constant-frequency (CW) segment is held, not linearized: a DFB's thermal
terms keep relaxing after the drive stops, so the optical frequency drifts by some 650 MHz over the
hold (the sim's default laser). A return of round trip tau then beats at |tau nu'(t) - f_D| there,
spread over many bins (lidard.dsp.ranging.threeseg), which is enough to choose between the two regimes of a
real receiver except where they meet (|f_D| ~ f_R), where their predictions of |f_D| differ by less
than the spread. There one ramp beat sits near DC and both readings agree on the sign; what is missing
is |f_D| precisely, for R = c (max(f_up, f_dn) - f_cw) / (2 kappa).

The drift is a property of the laser and its drive, the same in every period of the same drive.

* **Measurement** (:func:`hold_profile`): after the ILC, the monitor MZI is recorded over a whole
  period and averaged over many periods. Its fringe over the hold has phase 2 pi tau_m nu(t - tau_m/2)
  (the fringe runs at tau_m nu', 0.2-3.4 MHz on the default laser: tens of cycles over the hold, and
  averaging the repeatable fringe takes the laser's phase noise out). The profile nu(t) - nu(t_0) is
  stored with the linearization, in the chirp's frame (the up ramp raises nu). A quadrature monitor
  measures the drift's sign against the up ramp's. A real fringe's phase always rises, so its sign is
  taken from the physics: the thermal terms lag the drive, so when the drive stops after the down ramp
  the temperature (and nu) keeps moving the way the down ramp moved it, whatever the laser's tuning
  sign (the sim's laser model agrees: tests/e2e/test_e2e_motion.py).
* **Use** (:func:`dechirp_peak`): a return's CW segment multiplied by exp(-2 pi j tau nu(t - tau/2))
  is a tone at -f_D (its mirror term lies at +f_D, spread by 2 tau nu'), sharp to one bin; the sign
  of f_D is the ramps' (the sign of f_dn - f_up), and the tone's sub-bin peak on that side gives f_cw.
  Near the sensor the mirror is nearly as sharp, which is why the side must be known.
  tau comes from the ramps (f_R = hi - f_cw, iterated once).

Pure numpy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from ..spectrum.instfreq import analytic_phase
from ..spectrum.rangefft import C_M_PER_S
from ..spectrum.window import get_window

#: the stored profile's sample spacing (its drift is smooth: thermal time constants of >= ~5 us)
PROFILE_DT_S = 1e-7
#: zero padding of the dechirped CW segment's spectrum for the estimate (sub-bin peak by a parabola on
#: its log power)
_ZERO_PAD = 8
#: complex elements of zero-padded spectra per pass over the candidates (~64 MB)
PASS_ELEMENTS = 1 << 22


@dataclass(frozen=True)
class HoldProfile:
    """nu(t) - nu(t0) (Hz) of the held segment on the record's time axis: nu_hz[k] at t0_s + k dt_s."""

    t0_s: float
    dt_s: float
    nu_hz: tuple[float, ...]

    def __post_init__(self) -> None:
        nu = np.asarray(self.nu_hz, dtype=np.float64)
        if nu.ndim != 1 or nu.size < 2 or not np.all(np.isfinite(nu)):
            raise ValueError(f"hold profile: nu_hz must be >= 2 finite values, got shape {nu.shape}")
        if not (math.isfinite(self.dt_s) and self.dt_s > 0 and math.isfinite(self.t0_s)):
            raise ValueError(f"hold profile: need finite t0_s and dt_s > 0, got {self.t0_s!r}, {self.dt_s!r}")
        object.__setattr__(self, "nu_hz", tuple(float(v) for v in nu))

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> HoldProfile | None:
        if not d:
            return None
        try:
            return cls(float(d["t0_s"]), float(d["dt_s"]), tuple(d["nu_hz"]))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"hold profile: {exc} missing or malformed (need t0_s, dt_s, nu_hz)") from None

    def as_dict(self) -> dict[str, Any]:
        return {"t0_s": self.t0_s, "dt_s": self.dt_s, "nu_hz": list(self.nu_hz)}

    @cached_property
    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        # the sample times and values as arrays, once (at() runs on every dechirp pass)
        return self.t0_s + self.dt_s * np.arange(len(self.nu_hz)), np.asarray(self.nu_hz)

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """nu at the record times ``t_s`` (linear interpolation, held at the ends)."""
        return np.interp(t_s, *self._table)


def hold_profile(records: ArrayLike, fs_hz: float, start: int, mzi_delay_s: float) -> HoldProfile:
    """The hold's drift from monitor-MZI records (n_avg, n) of whole periods (up ramp, down ramp, hold),
    the hold from ``start``, in the chirp's frame: the up ramp raises nu.

    Complex records (quadrature monitor): the phase of the averaged I + jQ, its sign taken against the
    up ramp's. Real records: the averaged fringe's Hilbert phase, which always rises; the drift is taken
    to continue the down ramp's direction (module doc). Either way nu = phase / (2 pi tau_m), placed
    at t - tau_m / 2."""
    x = np.asarray(records)
    if x.ndim != 2 or not 0 < start < x.shape[1] - 16:
        raise ValueError(f"hold_profile: need records (n_avg, n) with the hold from sample {start}, got {x.shape}")
    seg = x[:, start:].mean(axis=0)
    if np.iscomplexobj(seg):
        phase = np.unwrap(np.angle(seg - seg.mean()))
        up = x[:, :start // 2].mean(axis=0)
        up_phase = np.unwrap(np.angle(up - up.mean()))
        sign = 1.0 if up_phase[-1] > up_phase[0] else -1.0
    else:
        # averaged over many periods the fringe is clean: its Hilbert phase, mirror-padded at the ends
        phase, _ = analytic_phase(seg - seg.mean(), pad=seg.size // 4)
        sign = -1.0
    nu = sign * (phase - phase[0]) / (2 * math.pi * mzi_delay_s)
    step = max(1, int(round(PROFILE_DT_S * fs_hz)))
    t0 = start / fs_hz - mzi_delay_s / 2
    return HoldProfile(t0, step / fs_hz, tuple(nu[::step]))


class CwPeak(NamedTuple):
    """A candidate's dechirped CW peak (:func:`dechirp_peak`), each (m,)."""

    f_hz: np.ndarray            # |f_D| (NaN where the band holds no bin)
    power: np.ndarray           # the peak's power (averaged over the records)
    noise: np.ndarray           # the spectrum's median power
    shoulder: np.ndarray        # the larger of the mean powers SHOULDER_BINS either side of the peak


def dechirp_peak(cw: np.ndarray, t_s: np.ndarray, profile: HoldProfile, tau_s: np.ndarray, fs_hz: float,
                 band_hz: tuple[np.ndarray, np.ndarray], side: np.ndarray, window: np.ndarray,
                 zero_pad: int = _ZERO_PAD) -> CwPeak:
    """|f_D| (Hz), its peak power, the spectrum's median power and its shoulder per candidate: ``cw``
    (m, n_avg, n) CW samples at record times ``t_s`` (n,), each candidate's round trip ``tau_s`` (m,),
    the band [lo, hi] (m,) of |f_D| searched on the ``side`` (m,) of 0 Hz where the tone lies: +1 for a
    receding target (the beat's CW phase is 2 pi (tau nu(t) - f_D t) with f_D = -2 v / lambda; its
    e^{+j psi} half lands on -f_D, the other half is the spread mirror). Powers are averaged over the
    records; NaN where the band holds no bin. ``zero_pad``: of the spectrum (the sub-bin peak's
    accuracy; 2 suffices to screen, 8 to estimate). The shoulder: the mean power over the bins
    ``SHOULDER_BINS`` (CW bins) below and above the peak, the larger of the two sides; bins within
    ``CW_GUARD_BINS`` of 0 Hz (the DC term and its window's main lobe) are left out, and a side with none left
    counts 0."""
    m, _, n = cw.shape
    nu = profile.at(t_s[None, :] - 0.5 * tau_s[:, None])              # (m, n)
    ref = np.exp(-2j * np.pi * tau_s[:, None] * (nu - nu[:, :1])) * window
    n_fft = zero_pad * n
    spec = np.fft.fft(cw * ref[:, None, :], n=n_fft, axis=-1)
    p = (spec.real ** 2 + spec.imag ** 2).mean(axis=1)                  # (m, n_fft)
    df = fs_hz / n_fft
    k = np.arange(1, n_fft // 2 - 1)
    rows = np.arange(m)[:, None]
    s = np.where(np.asarray(side) < 0, -1, 1)[:, None]
    idx = (s[:, :, None] * (k[None, :, None] + np.array([-1, 0, 1]))) % n_fft       # (m, len(k), 3)
    inside = (k * df >= band_hz[0][:, None]) & (k * df <= band_hz[1][:, None])
    ps_in = np.where(inside, p[rows, idx[..., 1]], -1.0)
    j = np.argmax(ps_in, axis=1)
    r = np.arange(m)
    # a peak on the band's edge is the skirt of something outside it (a static target's CW tone at DC,
    # a stronger return): not a tone inside the band
    edge = ~inside[r, np.maximum(j - 1, 0)] | ~inside[r, np.minimum(j + 1, k.size - 1)]
    best_p = np.where(edge, -1.0, ps_in[r, j])
    y0, y1, y2 = (np.log(np.maximum(p[r, idx[r, j, d]], 1e-300)) for d in range(3))
    den = y0 - 2 * y1 + y2
    frac = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    best_f = np.where(best_p > 0, (k[j] + np.clip(frac, -0.5, 0.5)) * df, np.nan)
    off = np.arange(SHOULDER_BINS[0] * zero_pad, SHOULDER_BINS[1] * zero_pad + 1)
    shoulder = np.zeros(m)
    for sign in (-1, 1):
        kk = k[j][:, None] + sign * off[None, :]                             # (m, offsets), this side
        use = (kk >= CW_GUARD_BINS * zero_pad) & (kk < n_fft // 2)
        ps = p[r[:, None], (s * kk) % n_fft]
        mean = np.where(use, ps, 0.0).sum(axis=1) / np.maximum(use.sum(axis=1), 1)
        shoulder = np.maximum(shoulder, mean)
    return CwPeak(best_f, np.maximum(best_p, 0.0), np.median(p, axis=1), shoulder)


# -- the frame DSP's use (lidard.dsp.ranging.threeseg.pair_frame_three) ---------------------------------------
# ``dsp`` below is the frame's lidard.dsp.frame.FrameDsp (typed Any: frame imports this module)
RampPair = Sequence[np.ndarray]        # [up ramp, down ramp] of a per-slot quantity, (n, K) each
# (range, velocity, valid, present, up index, down index), (n, K) each
PairSlots = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: a candidate's dechirped CW peak must stand this far over the spectrum's median (13 dB: an exponential
#: noise cell passes with probability exp(-20 ln 2) ~ 1e-6)
PEAK_SNR = 20.0
#: ... and this far over each of its shoulders (:func:`dechirp_peak`, SHOULDER_BINS CW bins either side):
#: the candidate's own return, dechirped with its own round trip, is one tone, whose shoulders hold its
#: Hann sidelobes (< -31 dB) and noise; a line spread over several bins is not that tone -- the CW beat
#: of another return (one beyond the range gate, whose ramp beats the gate cut, still beats in the held
#: segment within the Doppler band, smeared by the hold's drift over its round trip) dechirped with
#: the candidate's round trip. Without this test such a line confirmed noise peaks on one ramp as
#: near-range points (~1.6e-4 a pixel with a bright wall at 3-5.5 m, against the 1e-11 the detection is
#: set for). Noise alone: a shoulder is the mean of 4 CW bins x the records, within ~20 % of the noise
#: mean at 10 records, so a tone at PEAK_SNR passes with ~1.7x to spare.
TONE_CONTRAST = 10.0
#: bins of the CW spectrum left out at DC (the DC bin and its Hann window's main lobe): a regime that
#: predicts |f_D| inside them expects no CW beat (the static hypotheses of lidard.dsp.ranging.points)
CW_GUARD_BINS = 2
#: the shoulders' CW bins, from the peak: the four bins just outside the window's main lobe
SHOULDER_BINS = (CW_GUARD_BINS + 1, CW_GUARD_BINS + 4)
#: a shoulder is a line, not noise, when its mean stands this far over the spectrum's median (6 dB): only
#: then does TONE_CONTRAST apply. Noise alone puts a shoulder (the mean of 4 CW bins) there for ~0.5 % of
#: candidates at one record (the gamma tail; a side is the larger of two), fewer with more records,
#: so a tone in noise is judged by PEAK_SNR alone as before, while the lines that confirmed false
#: points stood 50-100x over the median
SHOULDER_LINE = 4.0
#: a lower ramp beat this many ramp bins from DC or more is estimated without bias: the ramps range it
RAMP_CLEAR_BINS = 4.0


@dataclass
class Candidates:
    """Pairs (or lone ramp peaks) whose |f_D| the CW segment must give: pixel row, slot, hi (Hz), the
    band of |f_D| searched, the sign of v (+1: the up ramp holds hi), and the largest lo accepted."""

    row: np.ndarray
    slot: np.ndarray
    hi: np.ndarray
    sign: np.ndarray
    lo_max: np.ndarray
    lo: np.ndarray                      # the lower ramp beat (Hz); 0 for a lone peak


def measure_boundary(dsp: Any, x: np.ndarray, profile: HoldProfile, cand: Candidates, cw_start: int, n_cw: int,
                     ramp_df_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range (m), velocity (m/s, positive receding) and acceptance per candidate, from the dechirped
    CW segment: R = c (hi - f_cw) / (2 kappa), v = sign lambda f_cw / 2 (docs/physics.md)."""
    t_s = (cw_start + np.arange(n_cw)) / dsp.fs_hz
    w = get_window(dsp.window, n_cw)
    kappa = dsp.chirp_rate_hz_per_s
    f_cw = 0.5 * cand.hi                                # first guess: the regimes meet at f_R = |f_D|
    ok = np.zeros(cand.row.size, dtype=bool)
    # candidates per pass: the zero-padded spectra of their records stay within ~64 MB
    step = max(1, PASS_ELEMENTS // (x.shape[1] * _ZERO_PAD * n_cw))
    for c0 in range(0, cand.row.size, step):
        sl = slice(c0, c0 + step)
        cw = x[cand.row[sl], :, cw_start:cw_start + n_cw].astype(np.float64)
        hi, lo_max = cand.hi[sl], cand.lo_max[sl]
        band = (np.maximum(0.5 * (hi - lo_max), 0.0), 0.5 * (hi + lo_max))
        # a screen (2x padding: scalloping <= 0.4 dB), then once more with tau from the ramps and this
        # f_cw, 8x padded, for the candidates that can pass (a first guess of tau off by lo / 2 smears
        # the tone by a few dB at most): most lone peaks are noise
        side = cand.sign[sl]
        f_new, p_peak, noise, shoulder = dechirp_peak(cw, t_s, profile, (hi - f_cw[sl]) / kappa, dsp.fs_hz,
                                                      band, side, w, zero_pad=2)
        f_cw[sl] = np.where(np.isfinite(f_new), f_new, f_cw[sl])
        ok_screen = np.zeros(cw.shape[0], dtype=bool)
        again = np.flatnonzero(p_peak >= 0.5 * PEAK_SNR * noise)
        if again.size:
            idx = np.arange(c0, c0 + cw.shape[0])[again]
            f2, p2, n2, s2 = dechirp_peak(cw[again], t_s, profile, (cand.hi[idx] - f_cw[idx]) / kappa, dsp.fs_hz,
                                          (band[0][again], band[1][again]), side[again], w)
            f_new[again], p_peak[again], noise[again], shoulder[again] = f2, p2, n2, s2
            f_cw[idx] = np.where(np.isfinite(f2), f2, f_cw[idx])
            ok_screen[again] = True
        ok[sl] = (ok_screen & np.isfinite(f_new) & (p_peak >= PEAK_SNR * noise) & is_tone(p_peak, shoulder, noise)
                  & (np.abs(2 * f_cw[sl] - hi) <= lo_max))
    # f_cw says which regime holds; where the lower ramp beat stands clear of DC (its real-signal
    # image biases it within a few bins) both ramps then give the range, as elsewhere (two linearized
    # ramps against one ramp and the shorter CW window); nearer DC, R = c (hi - f_cw) / (2 kappa)
    folded = np.abs(f_cw - 0.5 * (cand.hi + cand.lo)) < np.abs(f_cw - 0.5 * (cand.hi - cand.lo))
    f_r = np.where(folded, 0.5 * (cand.hi - cand.lo), 0.5 * (cand.hi + cand.lo))
    f_r = np.where(cand.lo >= RAMP_CLEAR_BINS * ramp_df_hz, f_r, cand.hi - f_cw)
    rng = C_M_PER_S * f_r / (2 * kappa)
    vel = cand.sign * dsp.wavelength_m * (cand.hi - f_r) / 2
    return rng, vel, ok


def is_tone(peak: np.ndarray, shoulder: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """Whether a dechirped CW peak is one tone: its shoulders are noise (SHOULDER_LINE), or it stands
    TONE_CONTRAST over them (:func:`dechirp_peak`'s figures)."""
    return (shoulder <= SHOULDER_LINE * noise) | (peak >= TONE_CONTRAST * shoulder)


def boundary_candidates(flat_f: RampPair, flat_valid: RampPair, pairs: PairSlots, cw_df_hz: float, ramp_df_hz: float) -> Candidates:
    """Ambiguous pairs (present, not valid), and ramp peaks left without a partner whose partner may
    sit under the DC guard (placed in a free slot): their |f_D| lies within lo_max / 2 of hi / 2."""
    (fu, fd), (vu, vd) = flat_f, flat_valid
    _, _, ok, seen, iu, idn = pairs
    a = np.take_along_axis(fu, np.maximum(iu, 0), axis=1)
    b = np.take_along_axis(fd, np.maximum(idn, 0), axis=1)
    amb = seen & ~ok & (iu >= 0) & (idn >= 0)
    r_a, s_a = np.nonzero(amb)
    hi_a, lo_a = np.maximum(a, b)[amb], np.minimum(a, b)[amb]
    sign_a = np.where(a[amb] >= b[amb], 1.0, -1.0)
    lone_r, lone_s, lone_hi, lone_sign = [], [], [], []
    used_u = (iu[:, :, None] == np.arange(fu.shape[1])).any(axis=1)       # peaks some pair holds
    used_d = (idn[:, :, None] == np.arange(fd.shape[1])).any(axis=1)
    free = ~seen
    for f, v, used, sign, which in ((fu, vu, used_u, 1.0, 0), (fd, vd, used_d, -1.0, 1)):
        # a second detection within a few bins of a paired peak of the same ramp is that return's
        # (a sidelobe, two surfaces unresolved), not a return of its own
        near_used = (np.abs(f[:, :, None] - np.where(used, f, np.inf)[:, None, :]) <= 3.0 * ramp_df_hz).any(axis=-1)
        for r, j in zip(*np.nonzero(v & ~used & ~near_used)):
            slots = np.flatnonzero(free[r])
            if slots.size == 0:
                continue
            free[r, slots[0]] = False
            lone_r.append(r)
            lone_s.append(slots[0])
            lone_hi.append(f[r, j])
            lone_sign.append(sign)
            (iu if which == 0 else idn)[r, slots[0]] = j
    lo_lone = 3.0 * ramp_df_hz                     # a ramp beat closer to DC than this is not detected
    return Candidates(row=np.concatenate([r_a, np.asarray(lone_r, dtype=np.int64)]),
                      slot=np.concatenate([s_a, np.asarray(lone_s, dtype=np.int64)]),
                      hi=np.concatenate([hi_a, np.asarray(lone_hi, dtype=np.float64)]),
                      sign=np.concatenate([sign_a, np.asarray(lone_sign, dtype=np.float64)]),
                      lo_max=np.concatenate([lo_a + 2 * ramp_df_hz + 2 * cw_df_hz,
                                             np.full(len(lone_r), lo_lone + 2 * cw_df_hz)]),
                      lo=np.concatenate([lo_a, np.zeros(len(lone_r))]))


def resolve_boundary(dsp: Any, x: np.ndarray, profile: HoldProfile, flat_f: RampPair, flat_valid: RampPair, pairs: PairSlots, *,
                     ramp_df_hz: float, cw_window: tuple[int, int]) -> None:
    """Update ``pairs`` = (range, velocity, valid, present, up index, down index), each (n, K), in
    place: candidates (:func:`boundary_candidates`) whose dechirped CW peak is found become valid
    points at R = c (hi - f_cw) / (2 kappa); lone peaks that fail leave their slot empty.
    ``cw_window``: (first sample, samples) of the CW segment used."""
    a, n_cw = cw_window
    cand = boundary_candidates(flat_f, flat_valid, pairs, dsp.fs_hz / n_cw, ramp_df_hz)
    if cand.row.size == 0:
        return
    rng, vel, ok, seen, iu, idn = pairs
    r_m, v_mps, good = measure_boundary(dsp, x, profile, cand, a, n_cw, ramp_df_hz)
    r, s = cand.row, cand.slot
    was_seen = seen[r, s].copy()
    # a lone peak whose CW tone is another point's of the same pixel (|f_D| within 3 CW bins) is not
    # confirmed by it: the tone is that return's (a spurious ramp peak near twice its |f_D|)
    f_cw = 2 * np.abs(v_mps) / dsp.wavelength_m
    others = ok[r] & seen[r] & (np.arange(ok.shape[1]) != s[:, None])
    f_other = 2 * np.abs(vel[r]) / dsp.wavelength_m
    taken = (others & (np.abs(f_other - f_cw[:, None]) < 3 * dsp.fs_hz / n_cw)).any(axis=1)
    good &= was_seen | ~taken
    rng[r[good], s[good]], vel[r[good], s[good]] = r_m[good], v_mps[good]
    ok[r, s] = good
    seen[r, s] = was_seen | good
    drop = ~was_seen & ~good                       # lone peaks not confirmed: no point in that slot
    iu[r[drop], s[drop]], idn[r[drop], s[drop]] = -1, -1
