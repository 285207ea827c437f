"""Benchmark: the linearization health check (issue 13; dissertation §2.2's ILC measurement, re-used).

On the embedded simulated bench (config/sim.toml, default [sim.tolerances]), through the daemon's
instrument and the real wire protocols:

1. cost per scan: the check's hardware time (its monitor records), its instrument time on the virtual
   clock (records plus bringing laser and HV up and down around them) and wall time (drive upload,
   acquisition, demodulation), against a full 128x128 frame's hardware time;
2. the residual chirp error of a fresh linearization, per number of records (the noise the threshold
   must stay above), and after TEC steps of 0.05 / 0.1 / 0.2 / 0.5 C with the stale drive, beside the
   expected slope error k dT x excursion x 0.8 / sqrt(12) (k = tec_response_per_c) and the range error
   it means at 1 m (k dT x 1 m);
3. whether each check exceeds ``scan.linearity_threshold_hz`` (with the noise guard, 3x the measured
   noise floor).

Run: python benchmarks/linearity_health.py [--repeats N]
"""

from __future__ import annotations

import argparse
import math
import statistics
import threading
import time

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import ScanRequest, open_instrument

STEPS_C = (0.0, 0.05, 0.1, 0.2, 0.5)
RECORDS = (8, 16, 32, 64)


def _with_records(cfg, n: int):
    return cfg.model_copy(update={"scan": cfg.scan.model_copy(update={"linearity_check_records": n})})


def _checks(inst, cal, repeats: int):
    return [inst.check_linearization(cal) for _ in range(repeats)]


def cost(inst, cal, repeats: int) -> dict:
    clock = inst._on_close.__self__.clock             # the embedded bench's virtual clock
    t0 = clock.now()
    hs = _checks(inst, cal, repeats)
    instrument_s = (clock.now() - t0) / repeats       # records + laser/HV up and down, as a lab would wait
    req = ScanRequest(pattern="roi", rows=(40, 56), cols=(40, 72), max_range_m=2.0)
    t0 = time.perf_counter()
    res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
    wall = time.perf_counter() - t0
    per_pixel_s = res.hardware_time_s / res.pixels_scanned
    frame_pixels = len(inst.optics.bonded_rows) * inst.optics.cols
    return {"records": hs[0].records, "hardware_s": statistics.mean(h.hardware_time_s for h in hs),
            "instrument_s": instrument_s,
            "wall_s": statistics.median(h.wall_time_s for h in hs),
            "roi_scan_wall_s": wall, "roi_pixels": res.pixels_scanned,
            "frame_hardware_s": per_pixel_s * frame_pixels, "frame_pixels": frame_pixels}


def noise_by_records(inst, cal, repeats: int) -> list[dict]:
    out = []
    base = inst.cfg
    for n in RECORDS:
        inst.cfg = _with_records(base, n)
        hs = _checks(inst, cal, repeats)
        out.append({"records": n, "residual_hz": statistics.mean(h.residual_hz for h in hs),
                    "max_hz": max(h.residual_hz for h in hs),
                    "noise_hz": statistics.mean(h.noise_floor_hz for h in hs),
                    "limit_hz": max(h.limit_hz for h in hs)})
    inst.cfg = base
    return out


def steps(inst, cal, repeats: int) -> list[dict]:
    tol = inst.cfg.sim.tolerances
    exc = inst.cfg.chirp.excursion_hz
    out = []
    for dt in STEPS_C:
        if dt:
            inst.inject_fault("tec_offset", offset_c=dt)
        hs = _checks(inst, cal, repeats)
        slope_err = tol.tec_response_per_c * dt
        out.append({"step_c": dt, "residual_hz": statistics.mean(h.residual_hz for h in hs),
                    "expected_hz": slope_err * exc * 0.8 / math.sqrt(12),
                    "range_err_mm_at_1m": slope_err * 1e3,
                    "exceeded": sum(h.exceeded for h in hs), "checks": len(hs)})
    inst.clear_faults("tec_offset")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="checks per figure (default 5)")
    args = ap.parse_args(argv)
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, bench="embedded")
    try:
        t0 = time.perf_counter()
        cal = inst.linearize()
        lin_wall = time.perf_counter() - t0
        c = cost(inst, cal, args.repeats)
        print(f"linearization health check, sim.toml, threshold {cfg.scan.linearity_threshold_hz / 1e3:.0f} kHz, "
              f"tec_response_per_c {cfg.sim.tolerances.tec_response_per_c:g}/C, excursion "
              f"{cfg.chirp.excursion_hz / 1e9:g} GHz")
        print(f"\ncost per scan ({c['records']} records): hardware {c['hardware_s'] * 1e3:.2f} ms "
              f"= {c['hardware_s'] / c['frame_hardware_s'] * 100:.3f} % of a full frame's "
              f"{c['frame_hardware_s']:.2f} s ({c['frame_pixels']} pixels); instrument time with the laser/HV "
              f"bring-up and bring-down {c['instrument_s'] * 1e3:.0f} ms "
              f"= {c['instrument_s'] / c['frame_hardware_s'] * 100:.1f} % of a frame; wall {c['wall_s'] * 1e3:.0f} ms "
              f"(a {c['roi_pixels']}-pixel ROI scan: {c['roi_scan_wall_s'] * 1e3:.0f} ms wall; "
              f"a linearization: {lin_wall:.1f} s wall)")
        print("\nfresh linearization: residual by records per check (mean / max over repeats)")
        print(f"{'records':>8} {'residual kHz':>13} {'max kHz':>8} {'noise kHz':>10} {'limit kHz':>10}")
        for r in noise_by_records(inst, cal, args.repeats):
            print(f"{r['records']:>8} {r['residual_hz'] / 1e3:>13.0f} {r['max_hz'] / 1e3:>8.0f} "
                  f"{r['noise_hz'] / 1e3:>10.0f} {r['limit_hz'] / 1e3:>10.0f}")
        print(f"\nTEC step with the stale drive ({cfg.scan.linearity_check_records} records per check)")
        print(f"{'step C':>7} {'residual kHz':>13} {'expected kHz':>13} {'range err mm @1 m':>18} {'exceeded':>9}")
        for r in steps(inst, cal, args.repeats):
            print(f"{r['step_c']:>7.2f} {r['residual_hz'] / 1e3:>13.0f} {r['expected_hz'] / 1e3:>13.0f} "
                  f"{r['range_err_mm_at_1m']:>18.2f} {r['exceeded']:>5}/{r['checks']}")
    finally:
        inst.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
