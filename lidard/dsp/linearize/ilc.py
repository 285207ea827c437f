"""Chirp linearization by iterative learning pre-distortion of the laser drive (dissertation §2.2).

Procedure (Fig. 2-3): send a drive period, record the monitor-MZI beat, turn it into the optical
frequency (Hilbert transform, :mod:`lidard.dsp.spectrum.instfreq`), compare with the *ideal* linear chirp
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
tuning either: the frequency is estimated in the drive frame (see :mod:`lidard.dsp.spectrum.instfreq`), in
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

Rooms: the measurement (demodulation, refinement, unfolding, errors) is
:mod:`lidard.dsp.linearize._measure`; the response fit and the update law :mod:`lidard.dsp.linearize._update`; this
module is the iteration driver (:func:`linearize`), whose state between measurements is one explicit
:class:`_IlcState`. :func:`linearize` is about 70 lines with its docstring: argument checks and
the loop (judge, record, converged?, step, measure), each step a function below.

Pure numpy/scipy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from ._measure import ChirpGeometry as ChirpGeometry  # public here: the chirp a caller hands to linearize
from ._measure import _Analysis, _Analyzer, _directions
from ._update import UpdateLaw, fit_fm_response, propose_drive  # noqa: F401  (fit_fm_response: public here too)
from ..spectrum.instfreq import check_finite_array, check_positive


MeasureFn = Callable[[np.ndarray, int], np.ndarray]


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

    def __getitem__(self, key: str) -> Any:  # allow it["up_rms_hz"] as in the task's dict notation
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
    meta: dict[str, Any] = field(default_factory=dict)



@dataclass(frozen=True)
class IlcSettings:
    """The knobs of one :func:`linearize` run (checked when it starts; a ValueError names a bad one).

    ``beta``: the learning gain (0, 10]; ``max_iter``: updates at most (14, the dissertation's count);
    ``roi``/``learn``: the fractions of each ramp where the nonlinearity is reported and where the error
    is learned (0 < roi < learn <= 1); ``averages``: periods averaged per measurement, growing up to
    ``max_averages`` (default: no growth) while the noise floor stops learning above ``target_frac`` of
    the excursion; ``q_cutoff_hz``: the Q filter's low pass on the drive; ``meas_cutoff_hz``: the
    frequency estimate's low pass; ``rel_tol``: an improvement below it twice running stops learning;
    ``grow_tol``: an error growing by more is rolled back and beta halved, down to ``min_beta``;
    ``abs_tol_frac``: a nonlinearity below this fraction of the excursion is done; ``refine``: the
    narrow-band re-estimate of the frequency; ``update``: the inverse-model law or the scalar one;
    ``max_drive_factor``/``max_drive_v``: no drive beyond that multiple of the initial peak, or beyond
    that voltage (the output stage's range), is ever sent.
    """

    beta: float = 0.8
    max_iter: int = 14
    roi: float = 0.8
    averages: int = 128
    learn: float = 0.92
    q_cutoff_hz: float = 1.0e6
    meas_cutoff_hz: float = 400e3
    rel_tol: float = 0.02
    grow_tol: float = 0.2
    min_beta: float = 0.05
    abs_tol_frac: float = 1e-6
    refine: bool = True
    update: Literal["inverse", "scalar"] = "inverse"
    max_drive_factor: float = 4.0
    max_drive_v: float | None = None
    max_averages: int | None = None
    target_frac: float = 4e-6


@dataclass(frozen=True)
class _IlcOptions:
    """The validated knobs of one :func:`linearize` run."""

    excursion_hz: float
    law: UpdateLaw                         # how each step is made (and the drive cap)
    max_iter: int
    rel_tol: float
    grow_tol: float
    min_beta: float
    abs_tol_frac: float
    target_frac: float
    max_avg: int


@dataclass
class _IlcState:
    """Everything the iteration carries from one measurement to the next."""

    u: np.ndarray                          # the drive last measured ...
    a: _Analysis                           # ... and what was measured
    first: _Analysis                       # the initial drive's measurement (for the reduction)
    cur_u: np.ndarray                      # the drive the next update starts from ...
    cur_a: _Analysis                       # ... and its measurement
    best_u: np.ndarray
    best_a: _Analysis
    best_k: int
    beta: float
    n_avg: int                             # grows when the noise floor stops learning too early
    slips: int
    k: int = 0
    stalled: int = 0
    converged: bool = False
    reason: str = "max_iter reached"
    iters: list[IlcIteration] = field(default_factory=list)


class _Plant:
    """The one way a drive is measured: ``measure`` checked for shape and finiteness, then analysed."""

    def __init__(self, measure: MeasureFn, an: _Analyzer) -> None:
        self.measure, self.an = measure, an

    def run(self, u: np.ndarray, n_avg: int) -> _Analysis:
        y = np.asarray(self.measure(u.copy(), n_avg))
        y = y.astype(np.complex128 if np.iscomplexobj(y) else np.float64)
        if y.ndim == 1:
            y = y[None, :]
        if y.ndim != 2 or y.shape[1] != self.an.n_adc:
            raise ValueError(f"measure returned shape {y.shape}; expected (n_avg, {self.an.n_adc})")
        check_finite_array("MZI samples from measure", y.view(np.float64))
        return self.an.analyse(y, u)


def _norm(pair: tuple[float, float]) -> float:
    return math.hypot(pair[0], pair[1])


def _check_knobs(s: IlcSettings) -> int:
    """Raise a ValueError naming the first bad setting; return the largest average count allowed."""
    q_cutoff_hz, meas_cutoff_hz, beta, roi, learn = s.q_cutoff_hz, s.meas_cutoff_hz, s.beta, s.roi, s.learn
    max_iter, update, max_drive_factor, max_drive_v = s.max_iter, s.update, s.max_drive_factor, s.max_drive_v
    averages, max_averages, target_frac = s.averages, s.max_averages, s.target_frac
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
    return max_avg


def _drive_cap(u0: np.ndarray, max_drive_factor: float, max_drive_v: float | None) -> dict[str, Any]:
    """The largest |drive| ever sent (relative to the plain drive, and the output stage's range) and
    how it reads in a stop reason; a plain drive already beyond ``max_drive_v`` is refused."""
    peak0 = float(np.abs(u0).max())
    if max_drive_v is not None and peak0 > max_drive_v:
        raise ValueError(f"drive0_v peaks at {peak0:.4g} V, beyond max_drive_v = {max_drive_v:.4g} V")
    cap_v = max_drive_factor * peak0 if max_drive_v is None else min(max_drive_factor * peak0, max_drive_v)
    return {"cap_v": cap_v,
            "cap_text": (f"{cap_v:.4g} V peak ({max_drive_factor:g} x the initial drive peak"
                         f"{'' if max_drive_v is None else f' or max_drive_v = {max_drive_v:.4g} V'})")}


def _judge(st: _IlcState, o: _IlcOptions) -> bool:
    """Accept the drive just measured (it becomes the start of the next update) or roll it back."""
    if st.k == 0:
        return True
    a = st.a
    # near the floor the error fluctuates with the noise: only growth beyond that is divergence
    floor = 3.0 * a.noise if math.isfinite(a.noise) else 0.0
    if max(a.err_rms) > (1 + o.grow_tol) * max(st.cur_a.err_rms) + floor:
        st.beta *= 0.5                     # roll back to the last good drive, learn more gently
        return False
    improvement = 1 - _norm(a.err_rms) / _norm(st.cur_a.err_rms)
    st.stalled = st.stalled + 1 if improvement < o.rel_tol else 0
    st.cur_u, st.cur_a = st.u, a
    if _norm(a.err_rms) < _norm(st.best_a.err_rms):
        st.best_u, st.best_a, st.best_k = st.u, a, st.k
    return True


def _average_more(st: _IlcState, o: _IlcOptions, plant: _Plant) -> None:
    """Measure the same drive with twice the averages while the noise floor alone stops learning."""
    a = st.a
    while (math.isfinite(a.noise) and max(a.rms) <= 2.0 * a.noise
           and max(a.rms) > o.target_frac * o.excursion_hz and 2 * st.n_avg <= o.max_avg):
        st.n_avg *= 2                      # the same drive, measured with less noise
        a = st.a = plant.run(st.u, st.n_avg)
        st.slips += a.slips
        st.cur_a = a
        if _norm(a.err_rms) <= _norm(st.best_a.err_rms) or st.best_k == st.k:
            st.best_u, st.best_a, st.best_k = st.u, a, st.k
        st.iters[-1] = replace(st.iters[-1], up_rms_hz=a.rms[0], down_rms_hz=a.rms[1],
                               up_error_hz=a.err_rms[0], down_error_hz=a.err_rms[1],
                               noise_floor_hz=a.noise, tuning_hz_per_v=a.tuning, phase_slips=a.slips,
                               averages=st.n_avg)


def _converged(st: _IlcState, o: _IlcOptions, accepted: bool, plant: _Plant) -> str:
    """Why learning has converged after this measurement (empty: it has not)."""
    a = st.a
    if st.k == 0:
        if max(a.rms) <= o.abs_tol_frac * o.excursion_hz:
            return "already linear: nonlinearity below abs_tol_frac of the excursion"
        return ""
    if not accepted:
        return ""
    _average_more(st, o, plant)
    a = st.a
    if math.isfinite(a.noise) and max(a.rms) <= 2.0 * a.noise:
        return "reached the measurement noise floor"
    if max(a.rms) <= o.abs_tol_frac * o.excursion_hz:
        return "nonlinearity below abs_tol_frac of the excursion"
    if st.stalled >= 2:
        return "error stopped improving"
    return ""


def _step(st: _IlcState, o: _IlcOptions) -> str:
    """Make the next drive into ``st.u`` (``st.k`` advanced); return why learning stops instead."""
    if st.k >= o.max_iter:
        return "max_iter reached"
    if st.beta < o.min_beta:
        return "beta backed off below min_beta"
    K = st.cur_a.tuning
    if not (math.isfinite(K) and K > 0):
        return "tuning slope not measurable"
    st.k += 1
    prop = propose_drive(st.cur_u, st.cur_a.err_drive, st.cur_a.ramps_nu, o.law, tuning_hz_per_v=K, beta=st.beta)
    if prop.beta != st.beta:               # the cap halved the gain: the record says so
        st.beta = prop.beta
        st.iters[-1] = replace(st.iters[-1], beta=st.beta)
    if prop.drive_v is None:
        return prop.reason
    st.u = prop.drive_v
    return ""


def _record(st: _IlcState, accepted: bool) -> None:
    a = st.a
    st.iters.append(IlcIteration(index=st.k, up_rms_hz=a.rms[0], down_rms_hz=a.rms[1], up_error_hz=a.err_rms[0],
                                 down_error_hz=a.err_rms[1], noise_floor_hz=a.noise, tuning_hz_per_v=a.tuning,
                                 beta=st.beta, phase_slips=a.slips, accepted=accepted, averages=st.n_avg))


def linearize(measure: MeasureFn, drive0_v: ArrayLike, chirp: ChirpGeometry,
              settings: IlcSettings | None = None) -> IlcResult:
    """Iteratively pre-distort ``drive0_v`` so that the MZI-measured chirp becomes linear (§2.2).

    ``measure(drive_v, n_avg)`` plays one period of ``drive_v`` (at ``fs_drive_hz``, repeated) and
    returns ``n_avg`` recorded periods of the monitor-MZI beat, shape ``(n_avg, 2 ramp_s fs_adc_hz)``,
    each aligned with the start of the drive period: real (one photodiode), or complex I + jQ for a
    quadrature monitor (``[monitor] quadrature``; phases averaged, see :mod:`lidard.dsp.linearize.quadrature`).
    ``chirp``: the rates, ramp, excursion and monitor delay; ``settings``: the learner's knobs
    (:class:`IlcSettings`; its defaults when None). Stops when the nonlinearity reaches twice the
    measured noise floor or stops improving by ``rel_tol``; a step whose error grows by more than
    ``grow_tol`` is rolled back and beta halved. Returns the best drive seen.

    Averaging: when the noise floor stops it while the nonlinearity is still above ``target_frac`` of
    the excursion, the same drive is measured again with twice the averages (up to ``max_averages``;
    default: no growth) and learning goes on. A broad-linewidth laser on a long MZI needs this: its
    averaged beat shrinks by exp(-pi linewidth tau_m) while the noise does not, and a narrow laser
    never pays for it. The default target, 4e-6 of the excursion, is what a >= 1000x reduction of a
    ~0.7 % RMS nonlinearity needs; the measurement itself is unchanged.
    """
    s = IlcSettings() if settings is None else settings
    if not callable(measure):
        raise TypeError("measure must be callable as measure(drive_v, n_avg)")
    u0 = check_finite_array("drive0_v", drive0_v, ndim=(1,)).copy()
    g = chirp.checked()
    max_avg = _check_knobs(s)
    n_drive = 2 * g.ramp_s * g.fs_drive_hz
    if abs(n_drive - u0.size) > 0.5:
        raise ValueError(f"drive0_v has {u0.size} samples; one period 2 ramp_s fs_drive_hz is {n_drive:g}")
    an = _Analyzer(g, roi=s.roi, learn=s.learn, meas_cutoff_hz=s.meas_cutoff_hz, directions=_directions(u0),
                   refine=bool(s.refine))
    if an.f_beat * g.ramp_s < 10:
        raise ValueError(f"MZI beat {an.f_beat:g} Hz gives < 10 fringes per ramp: mzi_delay_s too short")
    law = UpdateLaw(update=s.update, fs_drive_hz=g.fs_drive_hz, ramp_s=g.ramp_s, learn=s.learn,
                    q_cutoff_hz=s.q_cutoff_hz, min_beta=s.min_beta, **_drive_cap(u0, s.max_drive_factor, s.max_drive_v))
    o = _IlcOptions(excursion_hz=g.excursion_hz, law=law, max_iter=s.max_iter, rel_tol=s.rel_tol,
                    grow_tol=s.grow_tol, min_beta=s.min_beta, abs_tol_frac=s.abs_tol_frac, target_frac=s.target_frac,
                    max_avg=max_avg)
    plant = _Plant(measure, an)
    a = plant.run(u0, int(s.averages))
    st = _IlcState(u=u0, a=a, first=a, cur_u=u0, cur_a=a, best_u=u0, best_a=a, best_k=0, beta=float(s.beta),
                   n_avg=int(s.averages), slips=a.slips)
    while True:
        accepted = _judge(st, o)
        _record(st, accepted)
        reason = _converged(st, o, accepted, plant)
        if reason:
            st.converged, st.reason = True, reason
            break
        reason = _step(st, o)
        if reason:
            st.reason = reason
            break
        st.a = plant.run(st.u, st.n_avg)
        st.slips += st.a.slips
    first, best_a = st.first, st.best_a
    red = {"up": first.rms[0] / best_a.rms[0] if best_a.rms[0] > 0 else math.inf,
           "down": first.rms[1] / best_a.rms[1] if best_a.rms[1] > 0 else math.inf}
    return IlcResult(drive_v=st.best_u, iterations=st.iters, reduction=red, converged=st.converged,
                     tuning_hz_per_v=best_a.tuning, best_iteration=st.best_k, phase_slips=st.slips,
                     stop_reason=st.reason,
                     meta={"meas_cutoff_hz": s.meas_cutoff_hz, "q_cutoff_hz": s.q_cutoff_hz, "averages": st.n_avg,
                           "roi": s.roi, "learn": s.learn, "mzi_beat_hz": an.f_beat})
