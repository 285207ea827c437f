"""Imported once by the DSP pool's forkserver (:data:`lidard.dsp_pool.PRELOAD`), never by a
scan: the frame DSP run on a small made-up batch, so that every worker forked from the server starts with
the compiled kernels loaded (numba loads a kernel from its cache on the kernel's first call: ~0.35 s in
every worker otherwise, measured) and the DSP's per-process tables built. Where numba is missing the
numpy path is warmed alone. The values computed here are thrown away; a failure here only leaves
the workers cold (an exception would stop the forkserver, and with it the pool).
"""

from __future__ import annotations

import numpy as np

from .dsp.frame import FrameDsp
from .dsp.spectrum.jit import kernels


def _warm() -> None:
    kernels()        # load the compiled kernels now (a scan's DSP counts cells before it loads them)
    n = 256
    dsp = FrameDsp(ramp_samples=n, fs_hz=5e6, chirp_rate_hz_per_s=1e14, wavelength_m=1.55e-6, max_range_m=2.0)
    t = np.arange(2 * n) / dsp.fs_hz
    rng = np.random.default_rng(0)
    # two returns a few cells apart: the joint refinement's and the model-order test's kernels load too
    beat = np.round(2000 * np.cos(2 * np.pi * 4e5 * t) + 1000 * np.cos(2 * np.pi * 4.7e5 * t)
                    + rng.normal(0, 30, (4, 2, 2 * n))).astype(np.int16)
    dsp.process(beat, 1e-4)


try:
    _warm()
except Exception:      # a warm-up only: the workers then warm on their first batches
    pass
