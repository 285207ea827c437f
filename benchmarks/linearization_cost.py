"""CPU cost of one chirp linearization (``LidarInstrument.linearize()`` on the embedded bench) and the
ILC's measurements, per region and averaging schedule.

Prints the process CPU seconds of the linearization (the simulated bench included: its cost grows
with the periods averaged), the load average, and each ILC measurement: RMS nonlinearity and RMS
error against the ideal chirp over the ROI (up / down ramp, kHz), the noise floor, the averages and
whether the step was accepted. To compare trees, run it with PYTHONPATH set to each tree, alternated.

Variants (``--variant``):

* ``shipped``: the tree's own linearization;
* ``edges-after-centre``: the ILC as on main (ROI 0.8, learning 0.92, main's averaging schedule), then
  a second ILC run from its drive over the range window (ROI 0.9, learning 0.95) with few averages
  (``--edge-averages``, no growth) and at most ``--edge-steps`` steps at gain ``--edge-beta``: the
  cheap way to learn the window's edges, measured here (it does not converge: see
  docs/measured/26_range_linearity.md);
* ``edges-first``: the reverse order: the range window and its margin first (ROI 0.9, learning 0.95,
  ``--edge-averages`` periods, no growth, ``--edge-steps`` steps), then the ILC as on main (ROI 0.8,
  learning 0.92, main's averaging schedule) from that drive.

The tree's ``[chirp] linear_window`` sets the shipped region (config/sim.toml: "core", the default;
config/sim_far.toml: "range"); ``--linear-window`` overrides it.

Run: PYTHONPATH=<tree> python benchmarks/linearization_cost.py --config config/sim_far.toml [--variant edges-after-centre]
     [--max-averages N] [--scene config/scenes/cal_letters.toml] [--linear-window core|range]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too
from pathlib import Path
from typing import Any

def _print_run(res: Any) -> None:
    print(f"  ILC run: ROI {res.meta['roi']}, learning {res.meta['learn']}, stop: {res.stop_reason}")
    for it in res.iterations:
        print(f"    k{it.index:<2d} rms {it.up_rms_hz / 1e3:8.1f} / {it.down_rms_hz / 1e3:8.1f}  "
              f"error {it.up_error_hz / 1e3:8.1f} / {it.down_error_hz / 1e3:8.1f}  "
              f"noise {it.noise_floor_hz / 1e3:6.1f} kHz  averages {it.averages:5d}  "
              f"{'accepted' if it.accepted else 'rolled back'}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/sim_far.toml")
    ap.add_argument("--variant", choices=("shipped", "edges-after-centre", "edges-first"), default="shipped")
    ap.add_argument("--max-averages", type=int, default=None,
                    help="override the linearization's MAX_AVERAGES (averaging growth cap)")
    ap.add_argument("--edge-averages", type=int, default=32)
    ap.add_argument("--edge-steps", type=int, default=4)
    ap.add_argument("--edge-beta", type=float, default=0.8)
    ap.add_argument("--scene", default="config/scenes/empty.toml",
                    help="the bench's scene; the linearization's course differs with it (config/sim.toml on "
                         "this tree: 12 measurements with empty.toml, 19 with cal_letters.toml)")
    ap.add_argument("--linear-window", choices=("core", "range"), default=None,
                    help="override the config's [chirp] linear_window (trees that have the key)")
    args = ap.parse_args(argv)

    import lidard
    import lidard.instrument.calibration.linearization as lin_mod
    from lidard.config import load_config
    from lidard.instrument import open_instrument

    orig = lin_mod.ilc_linearize

    def traced(measure: Any, drive0: Any, geometry: Any, settings: Any) -> Any:
        edge = dataclasses.replace(settings, averages=args.edge_averages, max_averages=args.edge_averages,
                                   max_iter=args.edge_steps, beta=args.edge_beta, roi=0.9, learn=0.95)
        centre_s = dataclasses.replace(settings, roi=0.8, learn=0.92)
        if args.variant == "edges-after-centre":
            centre = orig(measure, drive0, geometry, centre_s)
            _print_run(centre)
            res = orig(measure, centre.drive_v, geometry, edge)
        elif args.variant == "edges-first":
            edges = orig(measure, drive0, geometry, edge)
            _print_run(edges)
            res = orig(measure, edges.drive_v, geometry, centre_s)
        else:
            res = orig(measure, drive0, geometry, settings)
        _print_run(res)
        return res

    lin_mod.ilc_linearize = traced
    if args.max_averages is not None:
        lin_mod.MAX_AVERAGES = int(args.max_averages)
    tree = Path(lidard.__file__).resolve().parents[1]      # the tree on PYTHONPATH: its own config
    env = dict(os.environ)
    if args.linear_window is not None:
        env["LIDARD__CHIRP__LINEAR_WINDOW"] = args.linear_window
    cfg = load_config(str(tree / args.config), environ=env)
    inst = open_instrument(cfg, scene_path=str(tree / args.scene), bench="embedded")
    print(f"tree {tree}, config {args.config}, scene {args.scene}, variant {args.variant}, "
          f"linear_window {getattr(cfg.chirp, 'linear_window', 'none (main)')}"
          + ("" if args.max_averages is None else f", MAX_AVERAGES {args.max_averages}"))
    t0 = cpu_time()
    inst.linearize()
    cpu = cpu_time() - t0
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"linearization CPU {cpu:.1f} s, load average {load}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
