"""Benchmark: the range and pointing calibrations on the simulated bench, before/after figures (issue 13).

The daemon's procedures (lidard.instrument.calibration.procedures: ``run_range_calibration`` with a
plate at 0.8, 1.1 and 1.4 m, then ``run_pointing_calibration`` with five spheres spread over the field)
run THROUGH THE INSTRUMENT on an embedded bench; the bench's truths stay hidden from them. Then the
CAL letters (config/scenes/cal_letters.toml: letters on the plane z = 0.8 m, cardboard at z = 0.9 m)
are scanned (an ROI of 12 x 32 beams) before and after, and scored two ways:

* range error along the ray against the bench's ray-cast truth (``Bench.ground_truth``);
* point-to-surface distance of x, y, z to the scene's two planes (z = 0.8 and z = 0.9 m, nearest),
  which does not trust the daemon's pointing model.

Truth modes: ``--bench-delay-s 201e-9`` builds the bench with that monitor MZI delay while the daemon
keeps the nominal 200 ns (the bench's own ``[sim.tolerances]`` off: the one deviation is known);
without it the bench uses its own tolerances (``[sim.tolerances]``, ``--seed``), whatever they are.

Run: python benchmarks/calibration.py [--bench-delay-s 201e-9] [--seed 5]
Prints one line per step (fitted values, residuals, wall seconds) and the before/after table.
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from lidard.instrument.calibration import run_pointing_calibration, run_range_calibration
from sim_devices.world.scene import Scene

CAL_ROI = ScanRequest(pattern="roi", rows=(40, 56), cols=(40, 72), max_range_m=2.0, formats=())
SPHERES = {"sphere": [{"centre": [x, y, 1.0], "radius": 0.035}
                      for x, y in [(0, 0), (0.09, 0.09), (-0.09, 0.09), (0.09, -0.09), (-0.09, -0.08)]]}
PLATES_M = (0.8, 1.1, 1.4)


def open_split(bench_delay_s: float):
    """The bench with ``bench_delay_s``, the daemon's instrument with the nominal configuration."""
    from lidard.instrument.compose import open_split_bench
    bench_cfg = load_config("config/sim.toml", environ={"LIDARD__MONITOR__DELAY_S": repr(bench_delay_s),
                                                        "LIDARD__SIM__TOLERANCES__ENABLED": "false"})
    return open_split_bench(load_config("config/sim.toml"), bench_cfg)


def score(inst, bench, lin) -> dict[str, float]:
    bench.set_scene(Scene.from_toml("config/scenes/cal_letters.toml"))
    res = inst.run_scan(CAL_ROI, lambda p: None, threading.Event(), lin)
    p = res.points[res.points["valid"] == 1]
    p = p[~bench.mixed_pixels(p["row"], p["col"])]          # edge blur is not what a calibration fixes
    rng_err = p["range"] - bench.ground_truth(p["row"], p["col"])
    z = p["z"].astype(np.float64)
    surf = np.minimum(np.abs(z - 0.8), np.abs(z - 0.9))      # both planes are perpendicular to z
    return {"points": int(len(p)), "range_rms_mm": float(np.sqrt(np.mean(rng_err ** 2)) * 1e3),
            "surface_rms_mm": float(np.sqrt(np.mean(surf ** 2)) * 1e3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bench-delay-s", type=float, default=None,
                    help="bench monitor delay with the daemon at the nominal 200 ns (tolerances off)")
    ap.add_argument("--seed", type=int, default=5, help="[sim.tolerances] seed of the tolerant bench")
    args = ap.parse_args(argv)
    if args.bench_delay_s is not None:
        inst = open_split(args.bench_delay_s)
    else:
        cfg = load_config("config/sim.toml", environ={"LIDARD__SIM__TOLERANCES__SEED": str(args.seed)})
        inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    try:
        t = time.perf_counter()
        lin = inst.linearize()
        print(f"linearization (nominal delay): {time.perf_counter() - t:.1f} s", flush=True)
        before = score(inst, bench, lin)
        t = time.perf_counter()
        run = run_range_calibration(inst, PLATES_M, linearization=lin)
        f = run.fit
        print(f"range calibration ({len(PLATES_M)} plates + re-linearization): {time.perf_counter() - t:.1f} s; "
              f"delay {f.delay_s * 1e9:.4f} +- {f.delay_stderr_s * 1e9:.4f} ns, zero {f.zero_offset_m * 1e3:+.3f} "
              f"+- {f.zero_offset_stderr_m * 1e3:.3f} mm, chi2 {f.chi2:.2f}/{f.dof}, pixel spread "
              f"{f.pixel_std_m * 1e6:.0f} um", flush=True)
        t = time.perf_counter()
        prun = run_pointing_calibration(inst, SPHERES, linearization=run.linearization, noise_m=f.pixel_std_m)
        pf = prun.fit
        print(f"pointing calibration: {time.perf_counter() - t:.1f} s; {pf.pointing}; residual {pf.rms_m * 1e3:.3f} mm "
              f"/ {pf.rms_px:.4f} px rms over {pf.n_points} points", flush=True)
        after = score(inst, bench, prun.linearization)
    finally:
        inst.close()
    print(f"{'CAL letters':<14}{'points':>8}{'range RMS (mm)':>16}{'surface RMS (mm)':>18}")
    for name, s in (("uncalibrated", before), ("calibrated", after)):
        print(f"{name:<14}{s['points']:>8}{s['range_rms_mm']:>16.3f}{s['surface_rms_mm']:>18.3f}")
    print(f"ratio uncalibrated/calibrated: range {before['range_rms_mm'] / after['range_rms_mm']:.1f}x, "
          f"surface {before['surface_rms_mm'] / after['surface_rms_mm']:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
