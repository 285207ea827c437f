"""Beat-synthesis throughput of sim_devices.world.synth (output samples per second, one core).

The simulated digitizer records one segment per trigger = one triangle period (up + down ramp,
2 x 80 us for the default 8.6 GHz chirp of config.Chirp). The ADC rate follows the scan's maximum
range: fs = oversample (2.5) x 2 x (2 gamma d_max / c), so the simulation works at the rate a scene
needs (§2.1 eq. 2-1; §4.4.1). Three workloads, each with/without laser phase noise and with/without
quantization (noise ASD 2e-8 V/rtHz on, dfb_default laser, one hit per segment at a random range):

  typical : 1024 segments x 640 samples (the brief's reference batch)
  2 m     : 1024 segments at fs(2 m)   ~ 7.2 MS/s  -> 1147 samples per segment
  150 m   :   32 segments at fs(150 m) ~ 538 MS/s  -> 86,000 samples per segment

plus the MZI-only capture H7's chirp linearization uses (64 segments, fs(150 m), 10 ns MZI).

Usage: python benchmarks/synthesis.py [--repeats N]
Median CPU time (time.process_time, one thread) of N runs (default 5) after one warm-up;
numbers printed, nothing asserted.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from lidard.config import Chirp, load_laser
from lidard.physics.constants import C_M_PER_S
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import (
    AdcSpec, Effects, HitBatch, MonitorMzi, sample_rate_for_range_hz, synthesize, trajectory,
)

FS_AWG_HZ = 200e6


def _time(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        # CPU time of this process: robust to other jobs sharing the machine (numpy runs these
        # kernels on one thread, so this is the per-core figure)
        t = time.process_time()
        fn()
        ts.append(time.process_time() - t)
    return statistics.median(ts)


def run_synthesis(repeats: int = 5, quick: bool = False) -> dict:
    """Every workload of the module docstring; M samples/s per core (median CPU time).

    ``quick`` shrinks the segment counts 8x (same per-sample work, noisier figure).
    """
    chirp = Chirp()
    laser = DfbLaser(load_laser("dfb_default"))
    t0 = time.perf_counter()
    traj = trajectory(laser, triangle_drive(chirp.excursion_hz, chirp.ramp_s, FS_AWG_HZ,
                                            laser.static_tuning_hz_per_v), FS_AWG_HZ)
    t_traj = time.perf_counter() - t0
    period = traj.period_s
    rng = np.random.default_rng(1)
    div = 8 if quick else 1

    workloads = [("typical", 1024 // div, 640 / period, 640, 2.0)]
    for d_max, n_seg in ((2.0, 1024 // div), (150.0, max(1, 32 // div))):
        fs = sample_rate_for_range_hz(d_max, chirp.rate_hz_per_s, oversample=2.5)
        workloads.append((f"{d_max:g} m", n_seg, fs, int(round(fs * period)), d_max))

    rows = []
    for name, n_seg, fs, n, d_max in workloads:
        d = rng.uniform(0.2 * d_max, 0.9 * d_max, n_seg)
        hits = HitBatch.from_targets(np.arange(n_seg), d, 0.2, radial_velocity_m_s=rng.normal(0, 1, n_seg))
        t_start = np.arange(n_seg) * period
        for pn in (False, True):
            for q in (True, False):
                adc = AdcSpec(fs, n, bits=8, input_range_v=1.0, quantize=q)

                def run():
                    synthesize(traj, adc, t_start, hits, rng=rng, effects=Effects(
                               noise_asd_v_per_rthz=2e-8, linewidth_hz=laser.linewidth_hz if pn else 0.0))

                dt = _time(run, repeats)
                rows.append({"workload": name, "segments": n_seg, "fs_hz": fs, "samples": n,
                             "phase_noise": pn, "quantize": q, "msamples_per_s": n_seg * n / dt / 1e6})

    fs = sample_rate_for_range_hz(150.0, chirp.rate_hz_per_s, oversample=2.5)
    n = int(round(fs * period))
    n_seg = 64 // div
    adc = AdcSpec(fs, n, bits=12, input_range_v=1.0)
    mzi = []
    for pn in (False, True):
        def run_mzi():
            synthesize(traj, adc, np.arange(n_seg) * period, None,
                       effects=Effects(linewidth_hz=laser.linewidth_hz if pn else 0.0), rng=rng,
                       mzi=MonitorMzi(10e-9, 0.3))

        dt = _time(run_mzi, repeats)
        mzi.append({"segments": n_seg, "samples": n, "fs_hz": fs, "phase_noise": pn,
                    "msamples_per_s": n_seg * n / dt / 1e6})
    return {"trajectory_s": t_traj, "trajectory_samples": traj.n, "rows": rows, "mzi": mzi,
            "beat_150m_hz": 2 * chirp.rate_hz_per_s * 150 / C_M_PER_S}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    r = run_synthesis(args.repeats)
    print(f"trajectory (dfb_default, AWG {FS_AWG_HZ / 1e6:.0f} MS/s, {r['trajectory_samples']} samples/period): "
          f"{r['trajectory_s'] * 1e3:.1f} ms (once per drive waveform)")
    print(f"{'workload':>9} {'segments':>8} {'fs MS/s':>8} {'samples':>8} {'phase noise':>11} "
          f"{'quantize':>8} {'M samples/s':>12}")
    for w in r["rows"]:
        print(f"{w['workload']:>9} {w['segments']:>8} {w['fs_hz'] / 1e6:>8.2f} {w['samples']:>8} "
              f"{'on' if w['phase_noise'] else 'off':>11} {'on' if w['quantize'] else 'off':>8} "
              f"{w['msamples_per_s']:>12.1f}")
    for m in r["mzi"]:
        print(f"MZI only (ILC measurement), {m['segments']} x {m['samples']} at {m['fs_hz'] / 1e6:.0f} MS/s, "
              f"phase noise {'on' if m['phase_noise'] else 'off'}: {m['msamples_per_s']:.1f} M samples/s "
              f"(2 channels written)")
    print(f"(max range check: 2 gamma d / c at 150 m = {r['beat_150m_hz'] / 1e6:.1f} MHz)")


if __name__ == "__main__":
    main()
