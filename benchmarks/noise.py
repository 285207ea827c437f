"""Cost of the records' white noise: numpy's ziggurat against the Box-Muller draw the bench uses.

sim_devices.world.gauss.standard_normal_f32 (float32 Box-Muller, float64 radius) against
``Generator.standard_normal(dtype=float32)`` (what the limit kernel, benchmarks/limit.py, draws),
for one frame batch of records (default 200 x 9,520 samples: a 40 MS/s three-segment record).
CPU time (time.process_time), best of N; the ratio is printed, nothing asserted.

    python benchmarks/noise.py [--rows 200] [--samples 9520] [--repeats 7]
"""

from __future__ import annotations

import argparse

import numpy as np

from sim_devices.world.gauss import standard_normal_f32

try:
    from benchmarks.chain_throughput import best_cpu_s
except ImportError:            # run as a script: benchmarks/ itself is on sys.path
    from chain_throughput import best_cpu_s


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=200)
    ap.add_argument("--samples", type=int, default=9520)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args(argv)
    shape = (a.rows, a.samples)
    rng = np.random.default_rng(0)
    zig = best_cpu_s(lambda: rng.standard_normal(shape, dtype=np.float32), a.repeats)
    bm = best_cpu_s(lambda: standard_normal_f32(rng, shape), a.repeats)
    n = a.rows * a.samples
    print(f"{a.rows} x {a.samples} float32 normals: ziggurat {zig * 1e3:.2f} ms ({zig / n * 1e9:.2f} ns/sample), "
          f"Box-Muller {bm * 1e3:.2f} ms ({bm / n * 1e9:.2f} ns/sample), ratio {bm / zig:.2f}")


if __name__ == "__main__":
    main()
