"""Benchmark: CAL letters on a bench with hidden tolerances, before and after the lab's calibrations (issue 13).

For each bench of :func:`benchmarks.tolerances.variants` (nominal, the default seeded draws, and each
tolerance alone at its bound), one embedded instrument is linearized, the CAL letters are scanned
and scored (uncalibrated), then the daemon's own procedures run THROUGH THE INSTRUMENT (range: a
plate at 0.8, 1.1 and 1.4 m; pointing: five 35 mm spheres at 1 m spread over the field; the bench
places them through the scene, the procedures get only the known geometry), and the same scan is
scored again. Scores (``benchmarks.tolerances.score_points``): range error along the true beam
against the ray-cast truth, and point-to-surface distance of x, y, z to the scene's true surfaces
(which does not trust the pointing model).

Run: python benchmarks/tolerances_calibrated.py [--full] [--only "default draws (uncalibrated)"]
``--full`` scans every bonded pixel (12,288) instead of the letters' region.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
import tomllib
from typing import Any

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import open_instrument
from lidard.instrument.calibration import run_pointing_calibration, run_range_calibration

try:
    from benchmarks.tolerances import SCENE, _machine, request, score_points, variants
except ImportError:     # run as a script: benchmarks/ itself is on sys.path
    from tolerances import SCENE, _machine, request, score_points, variants

PLATES_M = (0.8, 1.1, 1.4)
SPHERES = {"sphere": [{"centre": [x, y, 1.0], "radius": 0.035}
                      for x, y in [(0, 0), (0.09, 0.09), (-0.09, 0.09), (0.09, -0.09), (-0.09, -0.08)]]}


def calibrate(inst, lin) -> tuple[Any, dict]:
    """Range, then pointing calibration through the instrument; answers the linearization to scan
    with (redone against the range calibration's monitor delay) and the fitted figures."""
    t0 = time.perf_counter()
    run = run_range_calibration(inst, PLATES_M, linearization=lin)
    prun = run_pointing_calibration(inst, SPHERES, linearization=run.linearization, noise_m=run.fit.pixel_std_m)
    fitted = {"range": run.fit.fitted(), "pointing": prun.fit.fitted(), "pointing_residuals": prun.fit.residuals(),
              "wall_s": time.perf_counter() - t0}
    with open(SCENE, "rb") as f:
        inst.set_scene(tomllib.load(f))          # back to the CAL letters
    return prun.linearization, fitted


def run_bench(env: dict[str, str], req) -> dict[str, Any]:
    inst = open_instrument(load_config(CONFIG_DIR / "sim.toml", environ=env), scene_path=str(SCENE),
                           bench="embedded")
    try:
        bench = inst._on_close.__self__
        lin = inst.linearize()
        before = inst.run_scan(req, lambda p: None, threading.Event(), lin)
        out = {"truth": bench.truth().as_dict(), "pixels": int(before.pixels_planned),
               "before": score_points(before.points, bench.world.scene, bench.ground_truth, bench.mixed_pixels)}
        lin2, fitted = calibrate(inst, lin)
        after = inst.run_scan(req, lambda p: None, threading.Event(), lin2)
        out["after"] = score_points(after.points, bench.world.scene, bench.ground_truth, bench.mixed_pixels)
        out["fitted"] = fitted
        return out
    finally:
        inst.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="every bonded pixel (12,288)")
    ap.add_argument("--only", action="append", default=None, help="run only this bench (repeatable)")
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    a = ap.parse_args(argv)
    req = request(False, a.full)
    print(f"machine: {_machine()}; request {req.pattern} rows {req.rows} cols {req.cols}", flush=True)
    rows = {}
    for name, env in variants().items():
        if a.only and name not in a.only:
            continue
        r = run_bench(env, req)
        rows[name] = r
        b, c = r["before"], r["after"]
        print(f"{name:>32}: before range {1e3 * b['rms_range_m']:8.3f} mm surface {1e3 * b['rms_surface_m']:8.3f} mm"
              f" | after range {1e3 * c['rms_range_m']:6.3f} mm surface {1e3 * c['rms_surface_m']:6.3f} mm"
              f" ({c['points']}/{r['pixels']} px; calibrations {r['fitted']['wall_s']:.0f} s)", flush=True)
    print("\n| bench | range RMS before (mm) | point-to-surface RMS before (mm) | range RMS after (mm) "
          "| point-to-surface RMS after (mm) | points after |")
    print("|---|---|---|---|---|---|")
    for name, r in rows.items():
        b, c = r["before"], r["after"]
        print(f"| {name} | {1e3 * b['rms_range_m']:.3f} | {1e3 * b['rms_surface_m']:.3f} | "
              f"{1e3 * c['rms_range_m']:.3f} | {1e3 * c['rms_surface_m']:.3f} | {c['points']}/{r['pixels']} |")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1, default=str)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
