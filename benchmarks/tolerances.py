"""What the bench's hidden tolerances do to accuracy (issue 13 items 1 and 3): nominal against
uncalibrated, and one tolerance at a time.

Scans the CAL letters (config/scenes/cal_letters.toml, §4.4.3) on embedded benches built from
config/sim.toml, each with the ILC linearization first (the daemon's only calibration so far), and
scores every valid first return twice:

* range error along the beam: measured range minus the bench's truth for that pixel
  (``Bench.ground_truth``: the lens -> surface distance along the TRUE beam), so it isolates the
  range calibration (MZI delay, zero offset) from pointing;
* point-to-surface distance: the measured (x, y, z), placed by the daemon's NOMINAL pointing model,
  to the nearest true surface of the scene (``Scene.surface_distance``): a pointing error shows here.
  Its "pointing alone" column places the TRUE ranges along the daemon's beams (no noise, no range
  error): what the pointing error costs by itself. On the letters' flat plane a sideways error only
  shows at the letters' edges and as the small depth error d theta dtheta of a tilted beam, so
  rotation and k1 barely register here; scenes with depth structure off axis (spheres) see more.

Variants: the nominal bench (``[sim.tolerances] enabled = false``); the default draws (what
config/sim.toml gives, sim.seed = 1: an uncalibrated lab); and the sensitivity rows, each
tolerance alone at its default bound (``draw = false``, every other bound 0). For the range
tolerances the expected range error is worked out from the FMCW relation: the daemon scales its
chirp rate by the monitor fringe rate over the NOMINAL delay, so with a true delay tau (1 + eps) and
a zero offset z0 a surface at d reads (d + z0) / (1 + eps); its RMS over the scored pixels is the
"expected" column.

Calibrated columns come with the range and pointing calibrations: :func:`run_variant` takes
``calibrate(instrument)``, run after the linearization and before the scan, and
:func:`score_points` is the scorer any scan's points go through.

    python benchmarks/tolerances.py [--quick] [--full] [--json FILE]

``run_tolerances(quick=False, full=False, log=print) -> dict`` is the entry point for a report.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from typing import Any
from collections.abc import Callable

import numpy as np

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import ScanRequest, open_instrument

TOLERANCES = ("mzi_delay_rel", "zero_offset_m", "focal_rel", "decentre_px", "rotation_deg", "k1")
_ENV = "LIDARD__SIM__TOLERANCES__"
SCENE = CONFIG_DIR / "scenes" / "cal_letters.toml"


def variants() -> dict[str, dict[str, str]]:
    """name -> environment overrides of lidard.config for that bench."""
    out = {"nominal bench": {_ENV + "ENABLED": "false"}, "default draws (uncalibrated)": {}}
    for name in TOLERANCES:
        env = {_ENV + "DRAW": "false"}
        env.update({_ENV + other.upper(): "0" for other in TOLERANCES if other != name})
        out[f"{name} at its bound"] = env
    return out


def request(quick: bool, full: bool) -> ScanRequest:
    if full:
        return ScanRequest(pattern="raster", max_range_m=2.0)
    if quick:
        return ScanRequest(pattern="roi", rows=(56, 72), cols=(40, 72), max_range_m=2.0)
    # the letters at 0.8 m span about +-40 columns and +-17 rows around the centre (1.76 mm a beam)
    return ScanRequest(pattern="roi", rows=(40, 88), cols=(16, 112), max_range_m=2.0)


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def score_points(points: np.ndarray, scene, ground_truth: Callable | None = None,
                 mixed: Callable | None = None) -> dict[str, Any]:
    """Both scores of a scan's points (POINT_DTYPE records; valid first returns are scored).

    ``scene``: a ``sim_devices.world.scene.Scene`` (the true surfaces). ``ground_truth(rows, cols)``:
    the true range per pixel along the true beam (``Bench.ground_truth``); without it the range error
    is taken along each point's own ray (``Scene.range_error``), which mixes pointing into it.
    ``mixed(rows, cols)`` (``Bench.mixed_pixels``): pixels whose beam footprint crosses a target's
    outline are left out and counted (``mixed_pixels``): their returns blend two surfaces, which is edge
    blur, not the range or pointing error these scores measure (docs/physics.md, "Mixed pixels").
    """
    p = points[(points["valid"] == 1) & (points["return_index"] == 0)]
    n_mixed = 0
    if mixed is not None and len(p):
        edge = np.asarray(mixed(p["row"], p["col"]), dtype=bool)
        n_mixed, p = int(edge.sum()), p[~edge]
    xyz = np.stack([p["x"], p["y"], p["z"]], axis=1).astype(np.float64)
    if ground_truth is not None:
        range_err = p["range"].astype(np.float64) - ground_truth(p["row"], p["col"])
    else:
        range_err = scene.range_error(xyz)
    surf = scene.surface_distance(xyz)
    return {"points": int(len(p)), "mixed_pixels": n_mixed, "rms_range_m": _rms(range_err),
            "mean_range_m": float(np.nanmean(range_err))
            if len(p) else float("nan"), "rms_surface_m": _rms(surf),
            "p95_surface_m": float(np.percentile(surf, 95)) if len(p) else float("nan")}


def expected_range_rms(truth, d_m: np.ndarray) -> float:
    """RMS of (d + z0) / (1 + eps) - d over true ranges d: the range error the MZI delay and zero
    offset alone give (pointing does not move the range along the true beam)."""
    return _rms((d_m + truth.zero_offset_m) / (1.0 + truth.mzi_delay_rel) - d_m)


def run_variant(env: dict[str, str], req: ScanRequest,
                calibrate: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """Linearize, optionally ``calibrate(instrument)``, scan, and score one bench."""
    inst = open_instrument(load_config(CONFIG_DIR / "sim.toml", environ=env), scene_path=str(SCENE),
                           bench="embedded")
    try:
        bench = inst._on_close.__self__          # the embedded Bench (as tests/e2e and the report do)
        t0 = time.perf_counter()
        cal = inst.linearize()
        if calibrate is not None:
            calibrate(inst)
        res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
        wall = time.perf_counter() - t0
        out = score_points(res.points, bench.world.scene, bench.ground_truth, bench.mixed_pixels)
        p = res.points[(res.points["valid"] == 1) & (res.points["return_index"] == 0)]
        p = p[~bench.mixed_pixels(p["row"], p["col"])]
        truth = bench.truth()
        d_true = bench.ground_truth(p["row"], p["col"])
        # the pointing error alone, without noise: true ranges placed along the daemon's beams
        floor = bench.world.scene.surface_distance(inst.optics.directions(p["row"], p["col"]) * d_true[:, None])
        out.update(expected_rms_range_m=expected_range_rms(truth, d_true), pointing_floor_surface_m=_rms(floor),
                   pixels=int(res.pixels_planned), wall_s=wall, truth=truth.as_dict())
        return out
    finally:
        inst.close()


def run_tolerances(quick: bool = False, full: bool = False, log=print) -> dict[str, Any]:
    req = request(quick, full)
    rows = {}
    for name, env in variants().items():
        r = run_variant(env, req)
        rows[name] = r
        log(f"{name:>30}: range RMS {1e3 * r['rms_range_m']:8.3f} mm (expected {1e3 * r['expected_rms_range_m']:8.3f},"
            f" mean {1e3 * r['mean_range_m']:+8.3f})  surface RMS {1e3 * r['rms_surface_m']:7.3f} mm "
            f"(p95 {1e3 * r['p95_surface_m']:6.3f}, pointing alone {1e3 * r['pointing_floor_surface_m']:6.3f})  "
            f"{r['points']}/{r['pixels']} px  {r['wall_s']:.1f} s")
    return {"machine": _machine(), "request": {"pattern": req.pattern, "rows": req.rows, "cols": req.cols},
            "variants": rows}


def report_section(quick: bool, log=print) -> tuple[str, dict, list[tuple[str, str, str]]]:
    """(markdown, data, headline rows) for ``python -m benchmarks`` (its ``tolerances`` section).

    Not run with ``--quick``: eight benches, each linearized, take minutes."""
    if quick:
        return ("Not run with `--quick` (eight benches, each linearized): "
                "`python benchmarks/tolerances.py`.\n", {"skipped": "quick"}, [])
    r = run_tolerances(False, False, log)
    rows = [[name, f"{1e3 * v['rms_range_m']:.3f}", f"{1e3 * v['expected_rms_range_m']:.3f}",
             f"{1e3 * v['rms_surface_m']:.3f}", f"{1e3 * v['p95_surface_m']:.3f}",
             f"{1e3 * v['pointing_floor_surface_m']:.3f}", f"{v['points']}/{v['pixels']}"]
            for name, v in r["variants"].items()]
    head = ["bench", "RMS range error (mm)", "expected (mm)", "RMS point-to-surface (mm)", "p95 (mm)",
            "pointing alone, noise-free (mm)", "pixels"]
    md = ("CAL letters, ILC linearization only (no range or pointing calibration yet), "
          f"ROI rows {r['request']['rows']} cols {r['request']['cols']}; see docs/tolerances.md.\n\n"
          + "| " + " | ".join(head) + " |\n|" + "---|" * len(head) + "\n"
          + "".join("| " + " | ".join(row) + " |\n" for row in rows))
    drawn = r["variants"]["default draws (uncalibrated)"]
    headline = [("CAL letters, default tolerances, uncalibrated: RMS range / point-to-surface error",
                 f"{1e3 * drawn['rms_range_m']:.2f} / {1e3 * drawn['rms_surface_m']:.2f} mm",
                 "<= 0.3 / 0.5 mm after calibration (issue 13)")]
    return md, r, headline


def _machine() -> str:
    try:
        from benchmarks.machine import machine_facts
    except ImportError:       # run as a script: benchmarks/ itself is on sys.path
        from machine import machine_facts
    f = machine_facts()
    return (f"{f['cpu_model'] or 'unknown CPU'}, {f['cpus']} cores, Python {f['python']}, numpy {f['numpy']}, "
            f"commit {f['commit'] or 'unknown'}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small ROI (figures not conclusive)")
    ap.add_argument("--full", action="store_true", help="the full frame (every bonded pixel)")
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    args = ap.parse_args(argv)
    r = run_tolerances(args.quick, args.full)
    print(f"machine: {r['machine']}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(r, f, indent=1)


if __name__ == "__main__":
    main()
