"""Benchmark: range linearity over 0.8-45 m, plate by plate, and what removes the range-dependent error.

A nominal bench (``[sim.tolerances]`` off: true monitor delay = nominal, zero offset 0), so a plate's
mean raw range minus its true ray range is the instrument's own range error. The plate is measured
through the instrument exactly as the range calibration measures it
(lidard.instrument.calibration.procedures.measure_plate: centre pixels, the scan's DSP) at each
distance, after one linearization. Variants switch one suspect off at a time, to find the cause:

* ``as configured``: the configuration as shipped;
* ``no laser phase noise``: ``sim.effects.phase_noise = false`` (the laser's phase noise and hence the
  phase-noise compensation's work);
* ``ideal laser``: ``laser = "ideal"`` (no chirp nonlinearity to linearize, no phase noise);
* ``no receiver noise``: ``sim.effects.noise = false`` (estimator bias with SNR);
* ``no phase noise, monitor delay 100 / 300 ns``: the monitor MZI the ILC linearizes through at another
  delay (the bench's delay is the configuration's: a nominal bench), to see whether the error follows it;
* ``no phase noise, compensation off``: the scans without the monitor-based phase-noise compensation
  (``scan.phase_noise_compensation = "off"``), which also takes the chirp's deterministic error out of
  the targets it compensates;
* ``dfb_default`` (with and without phase noise): the other laser.

Run: python benchmarks/range_linearity.py [--config config/sim_far.toml] [--plates 0.8 1.4 5 20 45]
     [--variants "as configured" "ideal laser"] [--out docs/measured/26_range_linearity.md]
Prints one row per variant: error per plate (mm), with its standard error.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

VARIANTS = {
    "as configured": {},
    "no laser phase noise": {"LIDARD__SIM__EFFECTS__PHASE_NOISE": "false"},
    "ideal laser": {"LIDARD__LASER": "ideal"},
    "no receiver noise": {"LIDARD__SIM__EFFECTS__NOISE": "false"},
    "no phase noise, monitor delay 100 ns": {"LIDARD__SIM__EFFECTS__PHASE_NOISE": "false",
                                             "LIDARD__MONITOR__DELAY_S": "100e-9"},
    "no phase noise, monitor delay 300 ns": {"LIDARD__SIM__EFFECTS__PHASE_NOISE": "false",
                                             "LIDARD__MONITOR__DELAY_S": "300e-9"},
    "no phase noise, compensation off": {"LIDARD__SIM__EFFECTS__PHASE_NOISE": "false",
                                         "LIDARD__SCAN__PHASE_NOISE_COMPENSATION": "off"},
    "no phase noise, compensation on": {"LIDARD__SIM__EFFECTS__PHASE_NOISE": "false",
                                        "LIDARD__SCAN__PHASE_NOISE_COMPENSATION": "on"},
    "compensation on": {"LIDARD__SCAN__PHASE_NOISE_COMPENSATION": "on"},
    "dfb_default": {"LIDARD__LASER": "dfb_default"},
    "dfb_default, no phase noise": {"LIDARD__LASER": "dfb_default", "LIDARD__SIM__EFFECTS__PHASE_NOISE": "false"},
}


def measure(config: str, env: dict[str, str], plates: list[float]) -> list[tuple[float, float, float]]:
    from lidard.config import load_config
    from lidard.instrument import open_instrument
    from lidard.instrument.calibration.procedures import measure_plate
    from lidard.instrument.calibration.range import plate_scene
    base = {k: v for k, v in os.environ.items() if k.startswith("LIDARD__")}
    cfg = load_config(REPO / config, environ={**base, "LIDARD__SIM__TOLERANCES__ENABLED": "false", **env})
    inst = open_instrument(cfg, scene_path=str(REPO / "config/scenes/empty.toml"), bench="embedded")
    out = []
    try:
        lin = inst.linearize()
        for d in plates:
            inst.set_scene(plate_scene(d, size_m=max(0.6, 0.02 * d)))
            m = measure_plate(inst, inst.optics, d, lin, inst.applied)
            out.append((d, m.raw_range_m - m.known_range_m, m.sem_m))
    finally:
        inst.close()
    return out


def line_fit(rows: list[tuple[float, float, float]]) -> tuple[float, float, int]:
    """Weighted straight line (offset + scale) through the plate errors: its chi-square, the largest
    departure of a plate from it (m) and the degrees of freedom. The benchmark's test of linearity."""
    import numpy as np
    d, e, s = (np.array(x) for x in zip(*rows))
    s = np.maximum(s, 1e-7)
    a = np.stack([np.ones_like(d), d], axis=1) / s[:, None]
    coef = np.linalg.lstsq(a, e / s, rcond=None)[0]
    r = e - (coef[0] + coef[1] * d)
    return float(np.sum((r / s) ** 2)), float(np.max(np.abs(r))), d.size - 2


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/sim_far.toml")
    ap.add_argument("--plates", nargs="+", type=float, default=[0.8, 1.4, 5.0, 20.0, 45.0])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    lines = [f"config {args.config}, nominal bench; error = mean raw range - true ray range, mm (+- standard error)",
             f"load average {os.getloadavg()[0]:.1f}", "",
             "| variant | " + " | ".join(f"{d:g} m" for d in args.plates) + " | line: chi2 (dof), max departure mm | wall s |",
             "|---|" + "---|" * (len(args.plates) + 2)]
    print("\n".join(lines), flush=True)
    for name in args.variants:
        t0 = time.perf_counter()
        rows = measure(args.config, VARIANTS[name], args.plates)
        chi2, dev, dof = line_fit(rows) if len(rows) >= 3 else (float("nan"), float("nan"), 0)
        line = (f"| {name} | " + " | ".join(f"{e * 1e3:+.3f} +- {s * 1e3:.3f}" for _, e, s in rows)
                + f" | {chi2:.1f} ({dof}), {dev * 1e3:.3f} | {time.perf_counter() - t0:.0f} |")
        print(line, flush=True)
        lines.append(line)
    if args.out:
        Path(args.out).write_text(f"Command: `python benchmarks/range_linearity.py --config {args.config}`\n\n"
                                  + "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
