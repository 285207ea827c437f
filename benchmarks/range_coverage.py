"""Benchmark: does the range fit's stated standard error cover the hidden truth? (coverage over seeds)

For each bench seed (config/sim.toml, ``[sim.tolerances]`` on, ``sim.seed = k``: a new hidden monitor
delay and zero offset each time), one embedded instrument is linearized and the factory plates
(lidard.jobs.guided.FACTORY_PLATES_M, 0.8 / 1.1 / 1.4 m) are measured through it and fitted
(lidard.instrument.calibration.range.fit_range). The fitted delay and zero offset are compared with
the bench's truth (drawn by sim_devices.world.tolerances.draw_truth from the same configuration): the
normalised error z = (fit - truth) / stated standard error, and how often |z| <= 2 (a 2-sigma interval
that is honest covers the truth ~95 % of the time).

Run: python benchmarks/range_coverage.py [--seeds 50] [--out docs/measured/26_range_coverage.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def one(seed: int) -> dict:
    from lidard.config import load_config
    from lidard.instrument import open_instrument
    from lidard.instrument.calibration.procedures import measure_plate
    from lidard.instrument.calibration.range import fit_range, plate_scene
    from lidard.jobs.guided import FACTORY_PLATES_M
    from sim_devices.world.tolerances import draw_truth
    env = {"LIDARD__SIM__SEED": str(seed), "LIDARD__SIM__TOLERANCES__ENABLED": "true"}
    cfg = load_config(REPO / "config/sim.toml", environ=env)
    truth = draw_truth(cfg.sim.tolerances, nominal_mzi_delay_s=cfg.monitor.delay_s, seed=cfg.sim.seed)
    inst = open_instrument(cfg, scene_path=str(REPO / "config/scenes/empty.toml"), bench="embedded")
    try:
        lin = inst.linearize()
        ms = []
        for d in FACTORY_PLATES_M:
            inst.set_scene(plate_scene(d))
            ms.append(measure_plate(inst, inst.optics, d, lin, inst.applied))
    finally:
        inst.close()
    fit = fit_range(ms, cfg.monitor.delay_s)
    return {"seed": seed, "delay_err_s": fit.delay_s - truth.mzi_delay_s, "delay_se_s": fit.delay_stderr_s,
            "zero_err_m": fit.zero_offset_m - truth.zero_offset_m, "zero_se_m": fit.zero_offset_stderr_m,
            "chi2": fit.chi2, "rel": truth.mzi_delay_s / cfg.monitor.delay_s - 1}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    rows = []
    for k in range(1, args.seeds + 1):
        r = one(k)
        rows.append(r)
        print(f"seed {k}: delay {r['delay_err_s'] * 1e12:+.2f} +- {r['delay_se_s'] * 1e12:.2f} ps, zero "
              f"{r['zero_err_m'] * 1e6:+.1f} +- {r['zero_se_m'] * 1e6:.1f} um, chi2 {r['chi2']:.2f}", flush=True)
    zd = np.array([r["delay_err_s"] / r["delay_se_s"] for r in rows])
    zz = np.array([r["zero_err_m"] / r["zero_se_m"] for r in rows])
    de = np.array([r["delay_err_s"] for r in rows])
    lines = [f"Command: `python benchmarks/range_coverage.py --seeds {args.seeds}`; {len(rows)} benches, "
             f"{time.perf_counter() - t0:.0f} s wall at load average {load0:.1f} (2 shared cores).", "",
             "| quantity | mean error | RMS error | median stated SE | RMS of z | 2-sigma coverage |",
             "|---|---|---|---|---|---|",
             f"| delay | {de.mean() * 1e12:+.2f} ps | {np.sqrt(np.mean(de ** 2)) * 1e12:.2f} ps | "
             f"{np.median([r['delay_se_s'] for r in rows]) * 1e12:.2f} ps | {np.sqrt(np.mean(zd ** 2)):.1f} | "
             f"{np.mean(np.abs(zd) <= 2) * 100:.0f} % |",
             f"| zero offset | {np.mean([r['zero_err_m'] for r in rows]) * 1e6:+.1f} um | "
             f"{np.sqrt(np.mean([r['zero_err_m'] ** 2 for r in rows])) * 1e6:.1f} um | "
             f"{np.median([r['zero_se_m'] for r in rows]) * 1e6:.1f} um | {np.sqrt(np.mean(zz ** 2)):.1f} | "
             f"{np.mean(np.abs(zz) <= 2) * 100:.0f} % |"]
    print("\n".join(lines))
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
