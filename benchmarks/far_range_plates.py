"""Benchmark: which plate distances reach <= 2 mm at 150 m, and the far-range calibration procedure.

A bench with its hidden tolerances on (config/sim_far.toml: the broad-linewidth laser, quadrature
monitor; ``sim.seed`` = ``--seed``), every plate measured through the instrument as the range calibration
measures it (lidard.instrument.calibration.procedures.measure_plate) with the phase-noise compensation
``on`` for all of them: the far scans the record is for run with it on (auto: gates >= 60 m), and a range
record holds plates of one mode (lidard.instrument.calibration.setup.mode_differs). The procedure:

1. linearize; a far plate (``--early``, default 45 m) measured now, before any range fit, to show whether
   the uncalibrated scale lets it through;
2. the near plates (the factory's 0.8 / 1.1 / 1.4 m), fitted; the fit applied (the ILC re-linearizes
   against the fitted delay, as the daemon does);
3. the far plates (``--far``, default 5 / 20 / 45 m), then a check plate at ``--check`` (150 m).

Each subset of plates (near only; near + each far plate; near + all) is fitted; for each the table gives
the delay error against the bench's hidden truth, the range error that fit leaves at 150 m from the truth
(``(R + z0) tau_fit / tau_true - z0_fit - R``), the uncertainty it states there
(AppliedCalibrations.range_uncertainty_m, what a scan's sidecar says) and the check plate's measured
error under that fit (its raw range rescaled to the fit's delay, minus the fit's zero offset, minus the
true ray range; +- its standard error).

Run: python benchmarks/far_range_plates.py [--seed 1] [--far 5 20 45] [--check 150]
     [--out docs/measured/26_far_range.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

NEAR_M = (0.8, 1.1, 1.4)


def _measure(inst, d, lin):
    from lidard.instrument.calibration.procedures import measure_plate
    from lidard.instrument.calibration.range import CalibrationRefused, plate_scene
    inst.set_scene(plate_scene(d, size_m=max(0.6, 0.02 * d)))
    try:
        m = measure_plate(inst, inst.optics, d, lin, inst.applied)
        print(f"plate {d:g} m: raw - true {(m.raw_range_m - m.known_range_m) * 1e3:+.2f} mm, {m.n} pixels", flush=True)
        return m, None
    except CalibrationRefused as exc:
        print(f"plate {d:g} m refused: {exc}", flush=True)
        return None, str(exc)


def run(seed: int, far: list[float], check: float, early: float | None, laser: str | None = None) -> dict:
    from lidard.config import load_config
    from lidard.instrument import open_instrument
    from sim_devices.world.tolerances import draw_truth
    env = {"LIDARD__SIM__SEED": str(seed), "LIDARD__SIM__TOLERANCES__ENABLED": "true",
           "LIDARD__SCAN__PHASE_NOISE_COMPENSATION": "on", **({"LIDARD__LASER": laser} if laser else {})}
    cfg = load_config(REPO / "config/sim_far.toml", environ=env)
    truth = draw_truth(cfg.sim.tolerances, nominal_mzi_delay_s=cfg.monitor.delay_s, seed=cfg.sim.seed)
    inst = open_instrument(cfg, scene_path=str(REPO / "config/scenes/empty.toml"), bench="embedded")
    out: dict = {"truth": truth, "nominal_s": cfg.monitor.delay_s, "refused": {}, "laser": cfg.laser}
    try:
        lin = inst.linearize()
        if early is not None:
            m, why = _measure(inst, early, lin)
            out["early"] = (early, m, why)
        near = []
        for d in NEAR_M:
            m, why = _measure(inst, d, lin)
            if m is None:
                raise SystemExit(f"near plate {d} m refused: {why}")
            near.append(m)
        from lidard.instrument.calibration.range import fit_range
        f0 = fit_range(near, cfg.monitor.delay_s)
        inst.use_calibrations(dataclasses.replace(inst.applied, range_id="near", delay_s=f0.delay_s,
                                                  zero_offset_m=f0.zero_offset_m))
        lin2 = inst.linearize()
        out["near"], out["far"] = near, []
        for d in far:
            m, why = _measure(inst, d, lin2)
            if m is None:
                out["refused"][d] = why
            else:
                out["far"].append(m)
        out["check"] = _measure(inst, check, lin2)
        out["check_delay_s"] = f0.delay_s
    finally:
        inst.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--far", type=float, nargs="+", default=[5.0, 20.0, 45.0])
    ap.add_argument("--check", type=float, default=150.0)
    ap.add_argument("--early", type=float, default=45.0, help="a far plate before any range fit (0: none)")
    ap.add_argument("--laser", default=None, help="another laser preset than the config's (LIDARD__LASER)")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    from lidard.instrument.calibration.applied import AppliedCalibrations
    from lidard.instrument.calibration.range import CalibrationRefused, fit_range
    from lidard.store import CalibrationRecord
    t0, c0, load0 = time.perf_counter(), cpu_time(), os.getloadavg()[0]
    r = run(args.seed, args.far, args.check, args.early or None, args.laser)
    truth, R = r["truth"], args.check
    chk, chk_why = r["check"]
    lines = [(f"Command: `python benchmarks/far_range_plates.py --seed {args.seed} --far "
             f"{' '.join(f'{d:g}' for d in args.far)} --check {R:g}{f' --laser {args.laser}' if args.laser else ''}`; "
             f"config/sim_far.toml with laser {r['laser']}, hidden tolerances on "
             f"(true delay {truth.mzi_delay_s * 1e9:.4f} ns against {r['nominal_s'] * 1e9:g} ns nominal, zero offset "
             f"{truth.zero_offset_m * 1e3:.2f} mm), phase-noise compensation on for every plate. "
             f"{time.perf_counter() - t0:.0f} s wall, {cpu_time() - c0:.0f} s CPU at load average "
             f"{load0:.1f} (2 shared cores)."), ""]
    if "early" in r:
        d, m, why = r["early"]
        lines.append(f"Plate at {d:g} m before any range fit: " + (
            f"measured, error {(m.raw_range_m - m.known_range_m) * 1e3:+.1f} mm ({m.n} pixels)" if m is not None
            else f"refused: {why}"))
    for d, why in r["refused"].items():
        lines.append(f"Plate at {d:g} m after the near fit: refused: {why}")
    lines.append(f"Check plate at {R:g} m after the near fit: " + (
        f"{chk.n} pixels, standard error {chk.sem_m * 1e3:.3f} mm" if chk is not None else f"refused: {chk_why}"))
    lines += ["", (f"| plates (m) | chi2 (dof) | delay error ps | error at {R:g} m from the truth, mm | stated "
                   f"1-sigma at {R:g} m, mm | check plate at {R:g} m, measured error mm |"), "|---|---|---|---|---|---|"]
    near, far = r["near"], r["far"]
    subsets = [near] + [near + [m] for m in far] + ([near + far] if len(far) > 1 else [])
    for ms in subsets:
        name = " / ".join(f"{m.known_m:g}" for m in ms)
        try:
            f = fit_range(ms, r["nominal_s"])
        except CalibrationRefused as exc:
            lines.append(f"| {name} | refused: {str(exc)[:120]} | | | | |")
            continue
        applied = AppliedCalibrations.from_records(CalibrationRecord("fit", "range", 0.0, None, {}, f.fitted(), {}))
        left = (R + truth.zero_offset_m) * f.delay_s / truth.mzi_delay_s - f.zero_offset_m - R
        meas = "-" if chk is None else (
            f"{(chk.raw_range_m * f.delay_s / r['check_delay_s'] - f.zero_offset_m - chk.known_range_m) * 1e3:+.2f}"
            f" +- {chk.sem_m * 1e3:.2f}")
        lines.append(f"| {name} | {f.chi2:.1f} ({f.dof}) | {(f.delay_s - truth.mzi_delay_s) * 1e12:+.2f} "
                     f"| {left * 1e3:+.2f} | {applied.range_uncertainty_m(R) * 1e3:.2f} | {meas} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text("## Far range: plates for <= 2 mm at 150 m\n\n" + text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
