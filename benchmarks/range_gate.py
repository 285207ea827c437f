"""Benchmark: the honest range gate and the unresolved flag, through the instrument (issue 14).

Each configuration is linearized through the embedded simulated bench; an 8 x 8 pixel ROI (48
bonded pixels) is scanned at a 2 m maximum range against a retro-reflective wall (albedo 2.0) behind
nothing else at 1.2x, 2.5x and 5x that range. Printed per wall: points, valid points, valid points at a
wrong range (every one here: the wall is beyond the gate), points flagged ``aliased``. Configurations:
the default 100 dB decimation filter, a poor 20 dB one (tx 10 mW: its leak is bright), and "no filter"
(a 1e-6 dB stop band: what the bench did before issue 14; the DSP's alias ceiling is then the full
scale, so its leaks are flagged, not valid). Then a pane-and-sheet pair 10 and 20 mm apart at 1 m:
pixels, pixels flagged ``unresolved``, valid points, pixels with two valid points. Last, the cost of the
unresolved model-order test (lidard.dsp.ranging): the frame DSP on 4096 pixels with and without it (best of 3, one core).

Run: python benchmarks/range_gate.py [--roi 8]
"""

from __future__ import annotations

import argparse
import threading
import time
from unittest import mock

import numpy as np

from lidard.config import load_config
from lidard.dsp import frame
from lidard.dsp.ranging import ramp as ramp_model
from lidard.dsp.detect.gate import PointFlag
from lidard.instrument import ScanRequest, open_instrument

MAX_RANGE_M = 2.0
CONFIGS = {"100 dB filter (default)": {}, "20 dB filter, tx 10 mW": {"LIDARD__ADC__STOPBAND_DB": "20",
                                                                    "LIDARD__LINK__TX_POWER_W": "0.01"},
           "no filter (1e-6 dB)": {"LIDARD__ADC__STOPBAND_DB": "1e-6"}}


def wall(z_m: float) -> dict:
    return {"target": [{"kind": "plane", "point": [0, 0, z_m], "normal": [0, 0, -1], "reflectivity": 2.0}]}


def pair(dz_m: float) -> dict:
    return {"target": [
        {"kind": "plane", "point": [0, 0, 1.0], "normal": [0, 0, -1], "reflectivity": 0.5, "transmission": 0.5},
        {"kind": "plane", "point": [0, 0, 1.0 + dz_m], "normal": [0, 0, -1], "reflectivity": 2.0}]}


def scan(inst, cal, scene, roi: int):
    inst.set_scene(scene)
    req = ScanRequest(pattern="roi", rows=(64 - roi // 2, 64 + roi // 2), cols=(64 - roi // 2, 64 + roi // 2),
                      max_range_m=MAX_RANGE_M)
    return inst.run_scan(req, lambda p: None, threading.Event(), cal)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--roi", type=int, default=8, help="ROI side in pixels (default 8)")
    a = ap.parse_args(argv)
    print(f"{'configuration':<26} {'wall':>6} {'points':>7} {'valid':>6} {'valid wrong':>12} {'aliased':>8}")
    for name, env in CONFIGS.items():
        inst = open_instrument(load_config("config/sim.toml", environ=env), scene_path="config/scenes/empty.toml",
                               bench="embedded")
        try:
            cal = inst.linearize()
            for factor in (1.2, 2.5, 5.0):
                pts = scan(inst, cal, wall(factor * MAX_RANGE_M), a.roi).points
                valid = pts["valid"] == 1
                aliased = int(np.count_nonzero(pts["flags"] & PointFlag.ALIASED))
                # the wall is beyond the gate: any valid point is at a wrong range
                print(f"{name:<26} {factor:>5.1f}x {len(pts):>7} {int(valid.sum()):>6} {int(valid.sum()):>12} {aliased:>8}")
        finally:
            inst.close()
    inst = open_instrument(load_config("config/sim.toml"), scene_path="config/scenes/empty.toml", bench="embedded")
    try:
        cal = inst.linearize()
        print(f"\n{'pair spacing':<13} {'pixels':>7} {'unresolved px':>14} {'valid':>6} {'2 valid px':>11}")
        for dz in (0.010, 0.020):
            res = scan(inst, cal, pair(dz), max(a.roi, 16))
            pts = res.points
            pix = pts["row"].astype(np.int64) * 4096 + pts["col"]
            valid = pts["valid"] == 1
            unres = np.unique(pix[(pts["flags"] & PointFlag.UNRESOLVED) != 0]).size
            _, nv = np.unique(pix[valid], return_counts=True)
            print(f"{dz * 1e3:>9.0f} mm {res.pixels_planned:>7} {unres:>14} {int(valid.sum()):>6} {int((nv > 1).sum()):>11}")
    finally:
        inst.close()
    on, off = dsp_cost()
    print(f"\nframe DSP, 4096 pixels: {on * 1e3:.0f} ms with the shape test, {off * 1e3:.0f} ms without "
          f"(ratio {on / off:.2f})")
    return 0


def dsp_cost(n_pix: int = 4096) -> tuple[float, float]:
    """Seconds of FrameDsp.process on ``n_pix`` one-tone pixels, with and without the shape test."""
    dsp = frame.FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=8.6e9 / 80e-6, wavelength_m=1.55e-6,
                         max_range_m=2.0, max_speed_mps=0.4)
    rng = np.random.default_rng(0)
    t = np.arange(800) / 5e6
    x = 0.01 * np.cos(2 * np.pi * 1.0e6 * t)[None, None, :] + 1e-4 * rng.standard_normal((n_pix, 1, 800))
    dsp.process(x[:8])

    def best() -> float:
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            dsp.process(x)
            runs.append(time.perf_counter() - t0)
        return min(runs)

    with_test = best()
    with mock.patch.object(ramp_model, "unresolved", lambda spec, index, frac, valid, noise, **kw: np.zeros_like(valid)):
        without = best()
    return with_test, without


if __name__ == "__main__":
    raise SystemExit(main())
