"""One sweep task: the bench's world synthesis and the daemon's DSP for one configuration, target, seed.

This module is the OFFLINE COMPOSITION ROOT: like ``lidard.instrument`` it may import the simulator
(import-linter contract "Only the composition root starts the simulator"), and nothing else in
``lidard.offline`` does.

What a task computes (the choice, and why it keeps the figure honest, is in docs/scale-out.md):
``trials`` pixels, each captured ``scan.averages`` times, looking at a Lambertian plane that faces the
beam of a bonded pixel near the array centre at ``distance_m``. The pieces are the ones a scan on the
simulated bench uses, called directly instead of through the byte protocols:

* the world (``sim_devices.world.world.World``): ray cast, eq. 2-10 return with the FPSA's Table 4-4
  losses, beat amplitude G R sqrt(P_ref P_rx) (eq. 2-11), white noise of eqs. 2-16..2-18, 2-20/21;
* the bench's digitizer model: 16-bit records, the 8-bit core's quantization noise added as white
  noise when the record is wider than the core (``sim_devices.bench.capture``), Wiener phase noise of the
  laser's linewidth (unless the bench's fidelity rule finds it negligible), the monitor MZI when
  phase-noise compensation is on, and the digitizer's front end (anti-alias corner, quantizer at the
  resolution the daemon asks: ``sim_devices.digitizer.front_end.write_samples``);
* the daemon's signal path (``lidard.instrument.dsp_plan.plan_signal``, the one constructor the scan
  loop calls): the ADC plan (rate from the maximum range and the Doppler band of scan.max_speed_mps,
  the record with the chirp's constant segment), the phase-noise choice and the frame DSP
  (``lidard.dsp.frame.FrameDsp``: range FFT, OS-CFAR, estimator, the joint ranging and pairing),
  unchanged; the digitizer's decimation filter on the beat as the bench applies it.

The chirp is the configured one (``chirp.shape``, the three-segment chirp by default, as scans) as the
daemon drives the AWG (``lidard.instrument.acquisition.plain_drive``), LINEARIZED: the laser follows
the drive exactly (an ideal FM response). The daemon linearizes before it scans (§2.2), so a sweep of
scan performance starts from a converged linearization, and its DSP gets the held segment's drift a
linearization measures (:func:`calibration`: here the drive's own, exact); laser presets differ here
by their coherence time (phase noise, eq. 2-15) and RIN. Sweeping the linearization itself (residual
nonlinearity) would be a ``chirp.shape`` variant. tests/offline/test_offline_sweep_scan.py checks that
a task and a scan of the same pixel on the bench give the same points.
"""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass

import numpy as np

from drivers.digitizer import protocol as digitizer_protocol
from lidard.config import Config
from lidard.dsp.ranging.crlb import crlb_freq_var
from lidard.dsp.ranging.cwhold import PROFILE_DT_S
from lidard.dsp.detect.gate import PointFlag
from lidard.dsp.frame import FrameResult
from lidard.dsp.spectrum.jit import decide as decide_dsp_path
from lidard.instrument.acquisition import AWG_RATE_HZ, plain_drive
from lidard.instrument.dsp_plan import AdcPlan, DspCalibration, SignalPlan, plan_signal
from lidard.instrument.dsp_plan import phase_noise_on as pn_rule
from lidard.physics.budget import monitor_noise_asd, quantization_asd, snr_db
from lidard.physics.constants import C_M_PER_S
from sim_devices.digitizer.device import decimation_filter
from sim_devices.digitizer.front_end import write_samples
from sim_devices.world.fidelity import phase_noise_negligible
from sim_devices.world.scene import Scene
from sim_devices.world.synth import (
    AdcSpec, ChirpTrajectory, Effects, HitBatch, MonitorMzi, NoiseStream, synthesize, trajectory_from_frequency,
)
from sim_devices.world.world import BeamHits, World

from .spec import SweepTask

RECORD_BITS = 16          # the daemon's record format (lidard.instrument.dsp_plan.adc_plan)


def phase_noise_on(cfg: Config, max_range_m: float) -> bool:
    """The daemon's rule for scan.phase_noise_compensation at the nominal monitor delay."""
    return pn_rule(cfg.scan.phase_noise_compensation, max_range_m, cfg.monitor.delay_s)


def linear_trajectory(cfg: Config) -> ChirpTrajectory:
    """The linearized chirp: the daemon's drive for ``chirp.shape`` (at the AWG rate) through a laser
    that follows it exactly: nu - nu0 rises by the excursion over one ramp, falls, then holds (three-
    segment) along the drive's hold."""
    nu = plain_drive(cfg, 1.0)          # a 1 Hz/V tuning: the drive's volts are the frequency's Hz
    return trajectory_from_frequency(nu, AWG_RATE_HZ, nu0_hz=C_M_PER_S / cfg.chirp.wavelength_m)


def calibration(cfg: Config, traj: ChirpTrajectory, adc: AdcPlan) -> DspCalibration:
    """What a converged calibration of this bench gives the DSP: the nominal monitor delay (the
    synthesis uses it), no I/Q imbalance, and on the three-segment chirp the held segment's drift
    nu(t) - nu(t0) over the record's hold (``lidard.dsp.ranging.cwhold.HoldProfile``), exact from the chirp."""
    hold = None
    if cfg.chirp.shape == "three_segment" and adc.cw_samples > 1:
        t0 = adc.ramp_samples * 2 / adc.fs_hz
        t = t0 + PROFILE_DT_S * np.arange(int(adc.cw_samples / adc.fs_hz / PROFILE_DT_S) + 2)
        nu = traj.frequency_at(t)
        hold = {"t0_s": t0, "dt_s": PROFILE_DT_S, "nu_hz": (nu - nu[0]).tolist()}
    return DspCalibration(mzi_delay_s=float(cfg.monitor.delay_s), hold_profile=hold)


def target_pixel(task: SweepTask) -> tuple[int, int]:
    """A bonded row and column near the centre of the array (an unbonded row cannot be switched)."""
    rows = task.point.profile.bonded_rows
    return int(rows[len(rows) // 2]), task.point.profile.cols // 2


def _world(task: SweepTask, row: int, col: int) -> World:
    pt = task.point
    optics = pt.profile.optics(pt.cfg.lens, pt.cfg.chirp.wavelength_m)
    u = optics.directions(np.array([row]), np.array([col]))[0]
    target = {"kind": "plane", "point": (u * task.distance_m).tolist(), "normal": (-u).tolist(),
              "reflectivity": task.reflectivity, "velocity": (u * task.velocity_mps).tolist()}
    return World(pt.cfg, pt.profile, pt.laser, Scene.from_dict({"target": [target]}, source="sweep target"))


def _core_asd(cfg: Config, fs_hz: float) -> float:
    """The converter core's quantization noise in a record decimated on board (a record resolution
    above the core's bits, config.Adc.record_bits), as white noise: the bench's
    (sim_devices.bench.capture.SegmentSynthesizer._core_asd), V/sqrt(Hz)."""
    a = cfg.adc
    if not cfg.sim.effects.quantization or a.record_bits(fs_hz, RECORD_BITS) <= a.bits:
        return 0.0
    return quantization_asd(a.input_range_v, a.bits, a.max_sample_rate_hz)


def _noise_asd(cfg: Config, world: World, fs_hz: float) -> float:
    """The bench's white noise at the ADC input (sim_devices.bench.capture.SegmentSynthesizer._synthesize), V/sqrt(Hz)."""
    asd = world.white_noise_asd_v() if cfg.sim.effects.noise else 0.0
    return float(np.hypot(asd, _core_asd(cfg, fs_hz)))


def _monitor_asd(cfg: Config, rin_db_per_hz: float, fs_hz: float) -> float:
    """The bench's white noise on the monitor-MZI channel (sim_devices.bench.capture.SegmentSynthesizer.monitor_asd), V/sqrt(Hz)."""
    mon = cfg.monitor
    asd = 0.0
    if cfg.sim.effects.noise:
        asd = monitor_noise_asd(mon.amplitude_v, mon.power_w, cfg.detector.responsivity_a_per_w,
                                rin_db_per_hz)["total"]
    return float(np.hypot(asd, _core_asd(cfg, fs_hz)))


@dataclass(frozen=True)
class TaskFrame:
    """A task's pixels through the scan's DSP: the frame result and what produced it."""

    result: FrameResult
    plan: SignalPlan
    pixel: tuple[int, int]
    world: World
    hits: BeamHits
    noise_asd_v_per_rthz: float


def task_frame(task: SweepTask, rng: np.random.Generator | None = None,
               noise: NoiseStream | None = None) -> TaskFrame:
    """Synthesize ``task.trials`` pixels (each ``scan.averages`` records) and run the scan's DSP.
    ``rng``: the noise's generator (default: the task's own, from its seeds); ``noise``: the white
    noise's stream (default: keyed by ``rng``). Tests give the bench's, to draw the bench's noise."""
    pt = task.point
    cfg = pt.cfg
    traj = linear_trajectory(cfg)
    # the ADC plan does not depend on the calibration's values: planned once nominally for the hold's length
    adc_only = plan_signal(cfg, DspCalibration.nominal(cfg), max_range_m=cfg.scan.max_range_m).adc
    sig = plan_signal(cfg, calibration(cfg, traj, adc_only), max_range_m=cfg.scan.max_range_m,
                      estimator=pt.dsp.estimator)
    dsp, pn_on = sig.dsp, sig.phase_noise
    fs, rl = sig.adc.fs_hz, sig.adc.record_length
    avg, n = cfg.scan.averages, task.trials
    n_seg = n * avg
    row, col = target_pixel(task)
    world = _world(task, row, col)
    bh = world.beam_hits(np.full(n_seg, row), np.full(n_seg, col), np.ones(n_seg))
    hits = None
    if bh.beam.size:
        phase = None
        if bh.speckle_phase_rad is not None:    # as the bench: speckle targets' own beat phase
            plain = 2.0 * np.pi * np.mod(traj.nu0_hz * bh.tau_s, 1.0)
            phase = np.where(np.isnan(bh.speckle_phase_rad), plain, bh.speckle_phase_rad)
        hits = HitBatch(seg=bh.beam.astype(np.intp), tau_s=bh.tau_s, amplitude_v=bh.amplitude_v,
                        doppler_hz=-2.0 * bh.velocity_mps / cfg.chirp.wavelength_m, phase_rad=phase)
    adc = AdcSpec(sample_rate_hz=fs, n_samples=rl, bits=RECORD_BITS, input_range_v=cfg.adc.input_range_v)
    asd = _noise_asd(cfg, world, fs)
    linewidth = pt.laser.linewidth_hz if cfg.sim.effects.phase_noise else 0.0
    # as the bench: no Wiener phase noise where it cannot matter and no monitor channel needs it
    if not pn_on and (hits is None or phase_noise_negligible(hits.tau_s, hits.amplitude_v, linewidth, asd,
                                                             cfg.chirp.ramp_s, cfg.chirp.rate_hz_per_s)):
        linewidth = 0.0
    if rng is None:
        rng = np.random.default_rng([task.base_seed, task.seed, int(task.key[:12], 16)])
    syn = synthesize(traj, adc, np.zeros(n_seg), hits, rng=rng, noise=noise,
                     effects=Effects(noise_asd_v_per_rthz=asd, linewidth_hz=linewidth,
                                     beat_filter=decimation_filter(fs, cfg.adc.max_sample_rate_hz, cfg.adc.stopband_db)),
                     mzi=MonitorMzi(cfg.monitor.delay_s, cfg.monitor.amplitude_v,
                                    _monitor_asd(cfg, pt.laser.rin_db_per_hz, fs)) if pn_on else None)
    shape = (n, avg, rl)
    beat, over = _recorded(cfg, fs, syn.beat)
    beat = beat.reshape(shape)
    mzi = _recorded(cfg, fs, syn.mzi)[0].reshape(shape) if pn_on and syn.mzi is not None else None
    # the DSP's path settled first: a task's figures must not depend on the worker that ran it or on
    # the tasks it ran before (the tone fits' compiled and numpy paths agree only to rounding)
    decide_dsp_path()
    res = dsp.process(beat, syn.lsb_v, mzi=mzi,
                      mzi_delay_s=cfg.monitor.delay_s if pn_on else None, mzi_lsb_v=syn.lsb_v)
    # a pixel whose beat clipped in any record gives no valid point, as the scan's (lidard.raw.points):
    # its spectrum holds the clipping's harmonics, which the harmonic screen leaves to this rule
    clipped = (over | syn.overrange[:, 0]).reshape(n, avg).any(axis=1)      # channel 0: the beat
    res = res.refused(clipped[:, None], PointFlag.CLIPPED)
    return TaskFrame(result=res, plan=sig, pixel=(row, col), world=world, hits=bh, noise_asd_v_per_rthz=asd)


def _recorded(cfg: Config, fs_hz: float, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The digitizer's record of a channel's synthesized codes (n_seg, n): its analogue anti-alias
    corner and its quantizer at the resolution the daemon asks for (config.Adc.record_bits), as the
    bench's digitizer applies them (sim_devices.digitizer.front_end.write_samples); and the records
    that went over range there (n_seg,)."""
    n_seg, n = codes.shape
    pcfg = digitizer_protocol.Config(
        sample_rate_hz=round(fs_hz), record_length=n, segments=n_seg, channel_mask=1, bits=RECORD_BITS,
        input_range_mv=round(cfg.adc.input_range_v * 1000), resolution_bits=cfg.adc.record_bits(fs_hz, RECORD_BITS),
        bandwidth_hz=round(cfg.adc.bandwidth_hz))
    out = np.empty((n_seg, 1, n), np.int16)
    over = write_samples(out, codes[:, None, :], np.zeros((n_seg, 1), bool), pcfg)
    return out[:, 0, :], over[:, 0]


def run_task(task: SweepTask) -> dict:
    """Synthesize and range ``task.trials`` pixels; return the task's result row (see evaluate)."""
    t0 = time.perf_counter()
    tf = task_frame(task)
    pt, cfg, res, bh, asd = task.point, task.point.cfg, tf.result, tf.hits, tf.noise_asd_v_per_rthz
    dsp, pn_on, world = tf.plan.dsp, tf.plan.phase_noise, tf.world
    fs, r, rl = tf.plan.adc.fs_hz, tf.plan.adc.ramp_samples, tf.plan.adc.record_length
    avg, n = cfg.scan.averages, task.trials
    n_seg = n * avg
    truth_m = float(bh.range_m[0]) if bh.beam.size else task.distance_m
    amp_v = float(bh.amplitude_v[0]) if bh.beam.size else 0.0
    row_out = evaluate(res, truth_m, task.velocity_mps, tol_m=2.0 * dsp.range_resolution_m)
    link = world.link
    row_out.update(
        task_key=task.key, config_hash=pt.config_hash, distance_m=task.distance_m, true_range_m=truth_m,
        reflectivity=task.reflectivity, velocity_mps=task.velocity_mps, seed=task.seed, trials=n,
        averages=avg, sample_rate_hz=fs, ramp_samples=r, phase_noise_compensation=pn_on,
        amplitude_v=amp_v, noise_asd_v_per_rthz=asd,
        budget_snr_db=float(snr_db(link, task.distance_m, reflectivity=task.reflectivity)),
        crlb_range_m=crlb_range_m(amp_v, asd, fs, dsp.n_used, cfg.chirp.rate_hz_per_s, avg),
        samples=int(n_seg * rl * (2 if pn_on else 1)), elapsed_s=time.perf_counter() - t0,
        worker=f"{socket.gethostname()}:{os.getpid()}")
    return row_out


def crlb_range_m(amplitude_v: float, noise_asd: float, fs_hz: float, n_used: int, rate_hz_per_s: float,
                 averages: int) -> float:
    """Rife-Boorstyn bound on the range std of an up/down pair averaged over ``averages`` segments.

    d = c (f_up + f_down) / (4 gamma): var(d) = (c / 4 gamma)^2 * 2 var(f) / averages, with var(f)
    the bound for a real tone of amplitude A in white noise of variance ASD^2 fs / 2 per sample.
    """
    if amplitude_v <= 0 or noise_asd <= 0:
        return float("nan")
    snr = (amplitude_v**2 / 2.0) / (noise_asd**2 * fs_hz / 2.0)
    var_f = float(crlb_freq_var(snr, n_used, real=True, fs_hz=fs_hz))
    return float(C_M_PER_S / (4.0 * rate_hz_per_s) * np.sqrt(2.0 * var_f / averages))


def evaluate(res: FrameResult, truth_m: float, truth_velocity_mps: float, *, tol_m: float) -> dict:
    """Per-task tallies: a trial DETECTS the target when a valid point lies within ``tol_m`` of the
    true range (the nearest such point is its measurement); other valid points are false alarms.

    Sums, not only means, so that seeds pool exactly: RMSE over a distance = sqrt(sum_sq / n).
    """
    ok = res.present & res.valid
    err = np.where(ok, res.range_m - truth_m, np.inf)
    best = np.argmin(np.abs(err), axis=1)
    rows = np.arange(err.shape[0])
    e = err[rows, best]
    det = np.abs(e) <= tol_m
    ev = res.velocity_mps[rows, best][det] - truth_velocity_mps
    e = e[det]
    n_det = int(det.sum())
    return {
        "detected": n_det,
        "false_alarms": int(ok.sum() - n_det),
        "range_err_sum_m": float(e.sum()),
        "range_err_sq_sum_m2": float((e**2).sum()),
        "velocity_err_sq_sum": float((ev**2).sum()),
        "p_detect": n_det / max(err.shape[0], 1),
        "range_rmse_m": float(np.sqrt((e**2).mean())) if n_det else float("nan"),
        "velocity_rmse_mps": float(np.sqrt((ev**2).mean())) if n_det else float("nan"),
    }
