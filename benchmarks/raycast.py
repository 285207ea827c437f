"""Ray-casting throughput of sim_devices.world (rays per second, median of several runs).

Two workloads:
  1. 16,384 rays (a 128 x 128 FPSA beam grid) into a synthetic scene of 20 targets of mixed kinds
     (5 planes, 5 boxes, 5 spheres, 5 non-convex 12-vertex polygons);
  2. the dissertation's 3D-imaging scan (§4.4.3): 128 x 96 beams into
     config/scenes/cal_letters.toml.

Beam directions follow eq. 4-1: antenna offset (x, y) behind a lens of focal length f = 25 mm
points along (-x/f, -y/f, 1) normalised; the antenna pitch is chosen so that 128 antennas span the
16 deg FoV (pitch = 2 f tan 8 deg / 128 = 55 um, resolution 0.126 deg ~ 0.13 deg).

A third line measures the mixed-pixel footprint sampling (sim_devices.world.footprint): the bench's
per-pixel cast of a 128 x 128 frame with ``mixed_pixels`` on against off, for a scene without
edges (one infinite wall: the ratio should be ~1) and for a box in front of the wall (sub-rays only
around the box's edges).

Usage: python benchmarks/raycast.py [--repeats N] [--max-hits K]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import numpy as np

from sim_devices.world.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
FOCAL_M = 25e-3
FOV_DEG = 16.0
N_ANTENNAS = 128


def lens_directions(nx: int, ny: int) -> np.ndarray:
    pitch_m = 2 * FOCAL_M * math.tan(math.radians(FOV_DEG / 2)) / N_ANTENNAS
    x = (np.arange(nx) - (nx - 1) / 2) * pitch_m
    y = (np.arange(ny) - (ny - 1) / 2) * pitch_m
    xx, yy = np.meshgrid(x, y)
    d = np.column_stack([-xx.ravel() / FOCAL_M, -yy.ravel() / FOCAL_M, np.ones(xx.size)])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def synthetic_scene(seed: int = 1) -> Scene:
    """20 targets of mixed kinds spread over the FoV at 1-6 m (seeded)."""
    rng = np.random.default_rng(seed)
    t = math.tan(math.radians(FOV_DEG / 2))
    targets = []
    for i in range(20):
        z = float(rng.uniform(1.0, 6.0))
        c = [float(rng.uniform(-t, t) * z), float(rng.uniform(-t, t) * z), z]
        common = {
            "reflectivity": float(rng.uniform(0.05, 1.0)),
            "transmission": float(rng.choice([0.0, 0.0, 0.5])),
            "velocity": [0.0, 0.0, float(rng.uniform(-2, 2))],
        }
        kind = ("plane", "box", "sphere", "polygon")[i % 4]
        if kind == "plane":
            n = [float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)), -1.0]
            tg = {"kind": "plane", "point": c, "normal": n, "size": [0.1 * z, 0.08 * z]}
            if i == 0:
                del tg["size"]  # one infinite back wall
                tg["point"] = [0.0, 0.0, 7.0]
                tg["normal"] = [0.0, 0.0, -1.0]
        elif kind == "box":
            tg = {"kind": "box", "center": c, "size": (rng.uniform(0.03, 0.1, 3) * z).tolist(),
                  "rotation_deg": rng.uniform(-45, 45, 3).tolist()}
        elif kind == "sphere":
            tg = {"kind": "sphere", "center": c, "radius": float(rng.uniform(0.02, 0.06) * z)}
        else:
            m = 12
            ang = np.sort(rng.uniform(0, 2 * math.pi, m))
            r = rng.uniform(0.02, 0.06, m) * z
            verts = [[c[0] + float(rr * math.cos(a)), c[1] + float(rr * math.sin(a)), z]
                     for rr, a in zip(r, ang)]
            tg = {"kind": "polygon", "vertices": verts}
        targets.append({**tg, **common})
    return Scene.from_dict({"name": "bench20", "target": targets}, source="benchmark")


def measure(scene: Scene, d: np.ndarray, repeats: int, max_hits: int) -> tuple[float, float]:
    scene.cast(d, max_hits=max_hits)  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        scene.cast(d, max_hits=max_hits)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return med, d.shape[0] / med


def run_raycast(repeats: int = 9, max_hits: int = 4) -> dict:
    """Both workloads; rays per second (median of ``repeats`` after one warm-up)."""
    d128 = lens_directions(128, 128)
    bench = synthetic_scene()
    med, rate = measure(bench, d128, repeats, max_hits)
    hits = bench.cast(d128, max_hits=max_hits)
    mixed = {"rays": int(d128.shape[0]), "median_s": med, "rays_per_s": rate,
             "tests_per_s": rate * len(bench), "hits_per_ray": float(np.mean(hits.count))}
    letters = Scene.from_toml(ROOT / "config" / "scenes" / "cal_letters.toml")
    d96 = lens_directions(128, 96)
    med, rate = measure(letters, d96, repeats, max_hits)
    hits = letters.cast(d96, max_hits=max_hits)
    on_letters = int(np.count_nonzero(hits.target_index[:, 0] < len(letters) - 1))
    cal = {"rays": int(d96.shape[0]), "median_s": med, "rays_per_s": rate, "beams_on_letters": on_letters}
    return {"mixed20": mixed, "cal_letters": cal, "repeats": repeats, "max_hits": max_hits}


def _frame_cast_s(targets: list[dict], mixed: bool, repeats: int) -> float:
    """Median time of the bench's per-pixel cast (World cache filled from scratch) of a frame."""
    from lidard.config import load_config
    from sim_devices.world.world import World

    cfg = load_config(ROOT / "config" / "sim.toml")
    world = World(cfg, cfg.load_profile(), cfg.load_laser(), Scene())
    rows, cols = np.divmod(np.arange(128 * 128), 128)
    scene = Scene.from_dict({"mixed_pixels": mixed, "target": targets})
    times = []
    for _ in range(repeats):
        world.set_scene(scene)  # empties the per-pixel cache
        t0 = time.perf_counter()
        world._cast_pixels(rows, cols)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def footprint_cost(repeats: int = 5) -> dict:
    """Frame cast time with mixed pixels on / off: a wall (no edges) and a box before the wall."""
    wall = {"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1]}
    box = {"kind": "box", "center": [0.05, 0.0, 1.1], "size": [0.2, 0.2, 0.2]}
    out = {}
    for name, targets in (("wall", [wall]), ("box_on_wall", [box, wall])):
        off, on = _frame_cast_s(targets, False, repeats), _frame_cast_s(targets, True, repeats)
        out[name] = {"off_s": off, "on_s": on, "ratio": on / off}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--max-hits", type=int, default=4)
    args = ap.parse_args(argv)
    r = run_raycast(args.repeats, args.max_hits)
    m, c = r["mixed20"], r["cal_letters"]
    print(f"mixed 20 targets : {m['rays']:6d} rays  median {m['median_s'] * 1e3:8.2f} ms  "
          f"{m['rays_per_s'] / 1e6:6.3f} Mrays/s  ({m['tests_per_s']:.3g} ray-target tests/s; "
          f"{m['hits_per_ray']:.2f} hits/ray)")
    print(f"cal_letters 128x96: {c['rays']:6d} rays  median {c['median_s'] * 1e3:8.2f} ms  "
          f"{c['rays_per_s'] / 1e6:6.3f} Mrays/s  ({c['beams_on_letters']} beams on the letters)")
    print(f"(median of {args.repeats} runs after one warm-up, max_hits = {args.max_hits})")
    for name, f in footprint_cost(max(3, args.repeats // 2)).items():
        print(f"mixed pixels, {name:11s}: 128x128 frame cast {f['off_s'] * 1e3:7.1f} ms one ray, "
              f"{f['on_s'] * 1e3:7.1f} ms with footprints (ratio {f['ratio']:.2f})")


if __name__ == "__main__":
    main()
