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
  laser's linewidth, the monitor MZI when phase-noise compensation is on;
* the daemon's ADC plan (``lidard.instrument.scan_loop.adc_plan``: rate from the maximum range) and its
  DSP (``lidard.dsp.frame.FrameDsp``: range FFT, OS-CFAR, estimator, up/down pairing), unchanged.

The chirp is the LINEARIZED one (an ideal triangle of ``chirp.excursion_hz`` over ``chirp.ramp_s``):
the daemon linearizes before it scans (§2.2), so a sweep of scan performance starts from a converged
linearization; laser presets differ here by their coherence time (phase noise, eq. 2-15) and RIN.
Sweeping the linearization itself (residual nonlinearity) would be a ``chirp.shape`` variant.
"""

from __future__ import annotations

import os
import socket
import time

import numpy as np

from lidard.config import Config
from lidard.dsp.crlb import crlb_freq_var
from lidard.dsp.frame import FrameDsp, FrameResult
from lidard.instrument.scan_loop import adc_plan as daemon_adc_plan
from lidard.physics.budget import monitor_noise_asd, quantization_asd, snr_db
from lidard.physics.constants import C_M_PER_S
from sim_devices.world.scene import Scene
from sim_devices.world.synth import AdcSpec, HitBatch, synthesize, trajectory_from_frequency
from sim_devices.world.world import World

from .spec import SweepTask

RECORD_BITS = 16          # the daemon's record format (lidard.instrument.scan_loop.adc_plan)


def adc_plan(cfg: Config, max_range_m: float) -> tuple[float, int]:
    """(ADC rate, samples per ramp): the daemon's own plan for a scan to ``max_range_m``."""
    plan = daemon_adc_plan(cfg, max_range_m)
    return plan.fs_hz, plan.ramp_samples


def phase_noise_on(cfg: Config, max_range_m: float) -> bool:
    """The daemon's rule for scan.phase_noise_compensation ("auto": round trip >= 2 monitor delays).

    The scan loop's version takes a whole ScanRequest; tests/offline compare the two.
    """
    mode = cfg.scan.phase_noise_compensation
    if mode == "auto":
        return 2 * max_range_m / C_M_PER_S >= 2 * cfg.monitor.delay_s
    return mode == "on"


def linear_trajectory(cfg: Config, fs_hz: float, ramp_samples: int):
    """The linearized chirp: nu - nu0 rises by the excursion over one ramp, then falls (up ramp first)."""
    r = ramp_samples
    k = np.arange(2 * r, dtype=np.float64)
    s = np.where(k <= r, k / r, (2 * r - k) / r)
    return trajectory_from_frequency(cfg.chirp.excursion_hz * (s - 0.5), fs_hz,
                                     nu0_hz=C_M_PER_S / cfg.chirp.wavelength_m)


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


def _noise_asd(cfg: Config, world: World) -> float:
    """The bench's white noise at the ADC input (sim_devices.bench.capture.SegmentSynthesizer._capture), V/sqrt(Hz)."""
    eff = cfg.sim.effects
    asd = world.white_noise_asd_v() if eff.noise else 0.0
    if eff.quantization and RECORD_BITS > cfg.adc.bits:
        q = quantization_asd(cfg.adc.input_range_v, cfg.adc.bits, cfg.adc.max_sample_rate_hz)
        asd = float(np.hypot(asd, q))
    return asd


def _monitor_asd(cfg: Config, rin_db_per_hz: float) -> float:
    """The bench's white noise on the monitor-MZI channel (sim_devices.bench.capture.SegmentSynthesizer.monitor_asd), V/sqrt(Hz)."""
    eff, mon = cfg.sim.effects, cfg.monitor
    asd = 0.0
    if eff.noise:
        asd = monitor_noise_asd(mon.amplitude_v, mon.power_w, cfg.detector.responsivity_a_per_w,
                                rin_db_per_hz)["total"]
    if eff.quantization and RECORD_BITS > cfg.adc.bits:
        asd = float(np.hypot(asd, quantization_asd(cfg.adc.input_range_v, cfg.adc.bits, cfg.adc.max_sample_rate_hz)))
    return asd


def run_task(task: SweepTask) -> dict:
    """Synthesize and range ``task.trials`` pixels; return the task's result row (see evaluate)."""
    t0 = time.perf_counter()
    pt = task.point
    cfg = pt.cfg
    max_range = cfg.scan.max_range_m
    pn_on = phase_noise_on(cfg, max_range)
    fs, r = adc_plan(cfg, max(max_range, 1.5 * C_M_PER_S * cfg.monitor.delay_s / 2) if pn_on else max_range)
    avg, n = cfg.scan.averages, task.trials
    n_seg = n * avg
    row, col = target_pixel(task)
    world = _world(task, row, col)
    bh = world.beam_hits(np.full(n_seg, row), np.full(n_seg, col), np.ones(n_seg))
    hits = HitBatch(seg=bh.beam.astype(np.intp), tau_s=bh.tau_s, amplitude_v=bh.amplitude_v,
                    doppler_hz=-2.0 * bh.velocity_mps / cfg.chirp.wavelength_m) if bh.beam.size else None
    adc = AdcSpec(sample_rate_hz=fs, n_samples=2 * r, bits=RECORD_BITS, input_range_v=cfg.adc.input_range_v)
    asd = _noise_asd(cfg, world)
    linewidth = pt.laser.linewidth_hz if cfg.sim.effects.phase_noise else 0.0
    rng = np.random.default_rng([task.base_seed, task.seed, int(task.key[:12], 16)])
    syn = synthesize(linear_trajectory(cfg, fs, r), adc, np.zeros(n_seg), hits, noise_asd_v_per_rthz=asd,
                     linewidth_hz=linewidth, rng=rng, mzi_delay_s=cfg.monitor.delay_s if pn_on else None,
                     mzi_amplitude_v=cfg.monitor.amplitude_v if pn_on else None,
                     mzi_noise_asd_v_per_rthz=_monitor_asd(cfg, pt.laser.rin_db_per_hz) if pn_on else 0.0)
    dsp = FrameDsp(ramp_samples=r, fs_hz=fs, chirp_rate_hz_per_s=cfg.chirp.rate_hz_per_s,
                   wavelength_m=cfg.chirp.wavelength_m, max_range_m=max_range,
                   max_speed_mps=cfg.scan.max_speed_mps, window=cfg.scan.window, pfa=cfg.scan.pfa,
                   max_returns=cfg.scan.max_returns, estimator=pt.dsp.estimator)
    shape = (n, avg, 2 * r)
    mzi = syn.mzi.reshape(shape) if pn_on else None
    res = dsp.process(syn.beat.reshape(shape), syn.lsb_v, mzi=mzi,
                      mzi_delay_s=cfg.monitor.delay_s if pn_on else None, mzi_lsb_v=syn.lsb_v)
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
        samples=int(n_seg * 2 * r * (2 if pn_on else 1)), elapsed_s=time.perf_counter() - t0,
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
