"""Cost of the records' white noise: numpy's ziggurat against the bench's counter-based generator.

sim_devices.world.gauss (SplitMix64 words, Box-Muller with polynomial log and sine) on its numpy path
(``normal_rows``) and compiled (``synth_kernels.noise_rows``), against
``Generator.standard_normal(dtype=float32)`` (what the limit kernel, benchmarks/limit.py, draws), for
one frame batch of records (default 200 x 9,520 samples: a 40 MS/s three-segment record). Also the
digitizer's compiled quantizer with the noise drawn in its pass (``noisy_quantize_rows``) against the
same quantizer adding no noise: the noise's marginal cost in the synthesis. CPU time
(time.process_time), best of N; ratios printed, nothing asserted.

    python benchmarks/noise.py [--rows 200] [--samples 9520] [--repeats 7]
"""

from __future__ import annotations

import argparse

import numpy as np

from sim_devices.world.gauss import NoiseStream, normal_rows, record_keys, stream_key

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
    n = a.rows * a.samples
    rng = np.random.default_rng(0)
    keys = record_keys(NoiseStream(stream_key(0)), 0, a.rows, "beat")
    std = np.ones(a.rows)
    zig = best_cpu_s(lambda: rng.standard_normal(shape, dtype=np.float32), a.repeats)
    npy = best_cpu_s(lambda: normal_rows(keys, a.samples, std), a.repeats)
    print(f"{a.rows} x {a.samples} float32 normals, ns/sample: numpy ziggurat {zig / n * 1e9:.2f}, "
          f"counter-based numpy path {npy / n * 1e9:.2f} (ratio {npy / zig:.2f})")
    try:
        from sim_devices.world import synth_kernels as k
    except ImportError:
        print("numba not installed: no compiled figures")
        return
    out = np.empty(shape, np.float32)
    k.noise_rows(keys, std, out)                       # compiled (or loaded from numba's cache) first
    comp = best_cpu_s(lambda: k.noise_rows(keys, std, out), a.repeats)
    v = (rng.standard_normal(shape) * 50.0).astype(np.float32)
    codes, over = np.empty(shape, np.int16), np.empty(a.rows, bool)
    q = (np.float32(1.0), np.float32(-32768.0), np.float32(32767.0), codes, over)
    k.noisy_quantize_rows(v, keys, std, *q)
    k.quantize_rows(v, out, False, *q)
    fused = best_cpu_s(lambda: k.noisy_quantize_rows(v, keys, std, *q), a.repeats)
    plain = best_cpu_s(lambda: k.quantize_rows(v, out, False, *q), a.repeats)
    print(f"compiled: noise_rows {comp / n * 1e9:.2f} ns/sample (ziggurat / compiled {zig / comp:.2f}); "
          f"quantizer with the noise drawn in its pass {fused / n * 1e9:.2f}, without noise {plain / n * 1e9:.2f}: "
          f"the noise's marginal cost {(fused - plain) / n * 1e9:.2f} ns/sample")


if __name__ == "__main__":
    main()
