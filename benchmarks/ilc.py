"""Benchmark: ILC chirp linearization (dissertation §2.2, Fig. 2-4) on every laser preset.

Goes through the simulator's synthesis (sim_devices.world.synth: 8-bit MZI channel, Wiener phase
noise) with the shipped monitor delay (lidard.config.Monitor().delay_s) and reports, per preset: the
MZI-measured RMS nonlinearity per iteration and its reduction (up/down), the TRUE residual from the
laser model's nu(t) (fraction of the excursion), and the plain triangle's nonlinearity. For the
default preset also the -6 dB width of a 10 m target's Hann-windowed peak against the transform
limit (~2.0 bins). The dissertation's figures: 140x (up) / 600x (down) in 14 iterations.
Run: python benchmarks/ilc.py
"""

from __future__ import annotations

import numpy as np

from lidard.config import Monitor, load_laser, load_lasers
from lidard.dsp.linearize.ilc import IlcSettings, linearize
from lidard.dsp.linearize.ilc import ChirpGeometry
from lidard.instrument.calibration.linearization import MAX_AVERAGES, MAX_ITERATIONS   # the instrument's policy
from sim_devices.world.laser import DfbLaser, ramp_nonlinearity_hz, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, MonitorMzi, synthesize, trajectory

RAMP_S, EXC_HZ, FS = 80e-6, 8.6e9, 100e6
TAU_M = Monitor().delay_s
DISSERTATION = {"reduction_up": 140.0, "reduction_down": 600.0, "iterations": 14}


def _run(preset, seed=1, averages=32, max_iter=MAX_ITERATIONS, max_averages=MAX_AVERAGES, quadrature=False,
         **ilc_kw):
    laser = DfbLaser(preset)
    rng = np.random.default_rng(seed)
    n = int(2 * RAMP_S * FS)
    adc = AdcSpec(sample_rate_hz=FS, n_samples=n, bits=8, input_range_v=1.0)

    def measure(drive, n_avg):
        out = synthesize(trajectory(laser, drive, FS), adc, np.zeros(n_avg), None,
                         effects=Effects(linewidth_hz=laser.linewidth_hz), rng=rng,
                         mzi=MonitorMzi(TAU_M, 0.3, quadrature=quadrature))
        i = out.mzi.astype(np.float64) * adc.lsb_v
        return i + 1j * out.mzi_q.astype(np.float64) * adc.lsb_v if quadrature else i

    u0 = triangle_drive(EXC_HZ, RAMP_S, FS, laser.static_tuning_hz_per_v)
    res = linearize(measure, u0, ChirpGeometry(fs_drive_hz=FS, fs_adc_hz=FS, ramp_s=RAMP_S, excursion_hz=EXC_HZ,
                                               mzi_delay_s=TAU_M),
                    IlcSettings(averages=averages, max_iter=max_iter,
                                max_averages=max_averages, **ilc_kw))   # the instrument's averaging policy
    return laser, u0, res


def convergence(preset: str, seed: int = 1, quadrature: bool = False, max_averages: int = 512) -> dict:
    """ILC on one preset (by name) through the simulator; figures as the report needs them.
    ``quadrature``: the monitor read in quadrature (I + jQ, ``[monitor] quadrature``)."""
    laser, u0, res = _run(load_laser(preset), seed, quadrature=quadrature, max_averages=max_averages)
    n = int(RAMP_S * FS)
    t0 = np.array(ramp_nonlinearity_hz(laser.frequency_hz(u0, FS), n)) / EXC_HZ
    t1 = np.array(ramp_nonlinearity_hz(laser.frequency_hz(res.drive_v, FS), n)) / EXC_HZ
    return {
        "preset": preset,
        "iterations": [{"up_rms_hz": float(it.up_rms_hz), "down_rms_hz": float(it.down_rms_hz)}
                       for it in res.iterations],
        "reduction_up": float(res.reduction["up"]),
        "reduction_down": float(res.reduction["down"]),
        "true_residual_up": float(t1[0]),
        "true_residual_down": float(t1[1]),
        "converged": bool(res.converged),
        "excursion_hz": EXC_HZ,
        "plain_nonlinearity_pct": float(100.0 * t0.max()),
        "updates": len(res.iterations) - 1,
        "stop_reason": res.stop_reason,
        "mzi_delay_s": TAU_M,
        "quadrature": bool(quadrature),
    }


def peak_width_bins(laser, drive, distance_m=10.0, zp=16):
    fs = 500e6
    n = int(RAMP_S * fs)
    adc = AdcSpec(sample_rate_hz=fs, n_samples=n, bits=16, input_range_v=4.0, quantize=False)
    hits = HitBatch.from_targets([0], [distance_m], [1.0])
    out = synthesize(trajectory(laser, drive, FS), adc, np.array([0.0]), hits)
    x = out.beat[0]
    lo, hi = int(0.1 * n), int(0.9 * n)           # the ROI of the up ramp
    seg = x[lo:hi] - x[lo:hi].mean()
    spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size), zp * seg.size))
    k = int(np.argmax(spec))
    half = spec[k] / 2
    a = k
    while spec[a] > half:
        a -= 1
    b = k
    while spec[b] > half:
        b += 1
    return (b - a) / zp


def main():
    print(f"ILC: {TAU_M * 1e9:.0f} ns monitor MZI (shipped), 32 averages growing to 512 at the noise floor (the instrument's policy), 100 MS/s, ROI 80 %, max 14 updates")
    print(f"dissertation (Fig. 2-4): {DISSERTATION['reduction_up']:.0f}x up / {DISSERTATION['reduction_down']:.0f}x "
          f"down in {DISSERTATION['iterations']} iterations; target here >= 600x both in <= 10")
    print(f"{'preset (monitor)':35s} {'plain %':>7s} {'up':>8s} {'down':>8s} {'updates':>7s} {'conv':>5s} "
          f"{'true res up':>11s} {'true res dn':>11s}  stop")
    for name, quad in [(n, q) for q in (False, True) for n in load_lasers()]:
        r = convergence(name, quadrature=quad)
        print(f"{name + (' (quadrature)' if quad else ''):35s} {r['plain_nonlinearity_pct']:7.2f} {r['reduction_up']:7.0f}x {r['reduction_down']:7.0f}x "
              f"{r['updates']:7d} {r['converged']!s:>5s} {r['true_residual_up']:11.2e} {r['true_residual_down']:11.2e}"
              f"  {r['stop_reason']}")
    laser, u0, res = _run(load_laser("dfb_default"))
    w0, w1 = peak_width_bins(laser, u0), peak_width_bins(laser, res.drive_v)
    print(f"dfb_default, 10 m target, Hann -6 dB width: triangle {w0:.2f} bins, linearized {w1:.2f} bins "
          f"(transform limit 2.00; within 5 %: {abs(w1 / 2.0 - 1) <= 0.05})")


if __name__ == "__main__":
    main()
