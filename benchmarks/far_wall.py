"""Benchmark: far walls through the instrument with a quadrature monitor (issue 15, dissertation §2.3).

Each laser preset is linearized THROUGH THE INSTRUMENT (embedded simulated bench, drivers, digitizer
wire protocol; the ILC reduction printed is the instrument's own, measured through the monitor MZI),
then an 8 x 8 pixel ROI is scanned against a flat wall at each distance (off the 200 ns monitor grid;
distances not tuned for). A pixel counts as ranged when it has a valid point within one range
resolution cell of the ray-cast truth. The transmitter is raised to 100 mW (as config/sim_far.toml
and tests/e2e/test_e2e_phase_noise.py): the figure measures the phase noise, not the link budget.

Run: python benchmarks/far_wall.py [--lasers dfb_broad_linewidth,dfb_default] [--walls 103,137.3,171.9,198]
     [--quadrature true|false] [--ilc-only] [--tx-power-w 0.1] [--averages 2]
Prints one row per (laser, wall): ranged pixels / planned, and the ratio to the first laser's count.
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument

ROI = dict(rows=(60, 68), cols=(60, 68))


def wall(z_m: float) -> dict:
    return {"target": [{"kind": "plane", "point": [0.0, 0.0, z_m], "normal": [0.0, 0.0, -1.0],
                        "size": [120.0, 120.0], "up": [0.0, 1.0, 0.0], "reflectivity": 0.9}]}


def ranged(res, bench) -> int:
    pts = res.points
    truth = bench.ground_truth(pts["row"], pts["col"])
    good = (pts["valid"] == 1) & (np.abs(pts["range"] - truth) <= res.meta["dsp"]["range_resolution_m"])
    return len({(int(r), int(c)) for r, c in zip(pts["row"][good], pts["col"][good])})


def run_laser(laser: str, walls: list[float], quadrature: bool, ilc_only: bool, max_range_m: float,
              tx_power_w: float = 0.1, averages: int = 2) -> list[dict]:
    cfg = load_config("config/sim.toml", environ={"LIDARD__SIM__TOLERANCES__ENABLED": "false",   # nominal bench
                                                   "LIDARD__LASER": laser, "LIDARD__LINK__TX_POWER_W": str(tx_power_w),
                                                   "LIDARD__MONITOR__QUADRATURE": str(quadrature).lower()})
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    rows = []
    try:
        t0 = time.perf_counter()
        cal = inst.linearize()
        print(f"{laser}: ILC through the instrument ({cal.meta.get('monitor')}): up {cal.reduction['up']:.0f}x "
              f"down {cal.reduction['down']:.0f}x, {len(cal.iterations)} iterations, converged {cal.converged}, "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        if ilc_only:
            return rows
        for z in walls:
            inst.set_scene(wall(z))
            req = ScanRequest(pattern="roi", averages=averages, max_range_m=max_range_m, phase_noise_compensation="on", **ROI)
            res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
            rows.append({"laser": laser, "wall_m": z, "ranged": ranged(res, bench), "planned": res.pixels_planned,
                         "method": res.meta["dsp"]["phase_noise"]["method"]})
            print(rows[-1], flush=True)
    finally:
        inst.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lasers", default="dfb_broad_linewidth,dfb_default")
    ap.add_argument("--walls", default="103,137.3,171.9,198")
    ap.add_argument("--quadrature", default="true", choices=("true", "false"))
    ap.add_argument("--max-range-m", type=float, default=210.0)
    ap.add_argument("--ilc-only", action="store_true")
    ap.add_argument("--tx-power-w", type=float, default=0.1, help="transmit power (config/sim_far.toml's)")
    ap.add_argument("--averages", type=int, default=2)
    a = ap.parse_args()
    walls = [float(w) for w in a.walls.split(",")]
    rows = [r for laser in a.lasers.split(",")
            for r in run_laser(laser, walls, a.quadrature == "true", a.ilc_only, a.max_range_m,
                               a.tx_power_w, a.averages)]
    if rows:
        print("| laser | monitor | wall (m) | ranged / planned |")
        print("|---|---|---|---|")
        for r in rows:
            print(f"| {r['laser']} | {r['method']} | {r['wall_m']:g} | {r['ranged']} / {r['planned']} |")


if __name__ == "__main__":
    main()
