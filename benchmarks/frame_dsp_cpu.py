"""The frame DSP's CPU time on 1024 synthetic pixels of the scan's three-segment chirp (40 MS/s, 3200-sample
ramps, 2 m gate), one record each: ``one`` return per pixel, or ``two`` (a second, 0.7x, 3 cells behind on
the ramps). Best of 3 process() calls, process CPU time, one BLAS thread. For an A/B against another tree
run it with each tree on PYTHONPATH, alternated (the machine is shared):

    for t in /work/main $PWD; do PYTHONPATH=$t OPENBLAS_NUM_THREADS=1 python benchmarks/frame_dsp_cpu.py one; done
"""

from __future__ import annotations

import sys
import time

import numpy as np

from lidard.dsp.frame import FrameDsp


def main(kind: str = "one") -> None:
    dsp = FrameDsp(ramp_samples=3200, fs_hz=40e6, chirp_rate_hz_per_s=8.6e9 / 80e-6, wavelength_m=1.55e-6,
                   max_range_m=2.0, max_speed_mps=10.0, cw_samples=3120)
    rng = np.random.default_rng(0)
    n = 1024
    t = np.arange(9520) / 40e6
    f = 2 * 8.6e9 / 80e-6 * rng.uniform(0.5, 1.8, n) / 299792458.0
    x = np.cos(2 * np.pi * f[:, None] * t + rng.uniform(0, 6.28, (n, 1)))
    x[:, 6400:] = np.cos(2 * np.pi * 2e3 * t[6400:])             # a static return's CW line near DC
    if kind == "two":
        f2 = f + 2 * 8.6e9 / 80e-6 * 3 * 0.01743 / 299792458.0
        x[:, :6400] += 0.7 * np.cos(2 * np.pi * f2[:, None] * t[:6400] + 1.0)
    x = (x + 0.01 * rng.standard_normal(x.shape))[:, None, :]
    dsp.process(x[:16])
    best = np.inf
    for _ in range(3):
        t0 = time.process_time()
        res = dsp.process(x)
        best = min(best, time.process_time() - t0)
    print(f"{kind}: {best:.3f} s CPU, {int((res.valid & res.present).sum())} valid points of {n} pixels")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "one")
