"""The static beat phase of :mod:`sim_devices.world.synth_grid` as one compiled pass (numba, optional).

:func:`sim_devices.world.synth_grid._fill` builds dPhi = G - f_h (H1 + f_h H2) - const with five numpy
passes over every (hit, sample) and a Python loop per residue and delay offset. The kernel here walks
each hit's record once, in sample order, with the same float64 operations in the same order (no
fast-math: no reassociation, no fused multiply-add), so it gives the numpy path's values bit for bit
(tests/sim_devices/world/test_synth_jit.py), and it runs without the GIL: the bench's synthesis
threads and the host's DSP threads proceed side by side.

The trigonometry stays in numpy: its float32 cosine is a SIMD loop (~0.7 ns a sample here) where a
compiled scalar cosine costs ~9 ns (measured on this 2-core EPYC), so a kernel running the cosine,
the noise and the quantization in the same pass would be slower, not faster.

Loading numba costs ~0.9 s of CPU once per process and the kernel saves ~5 ns a sample, so it is used
only when numba is already loaded in the process (the host's DSP loads it for large scans,
lidard.dsp.spectrum.jit) or once this process has asked for ``LOAD_AFTER_SAMPLES`` samples (the break-even of
that model); until then, and without numba, the numpy path runs. ``LIDARD_DSP_JIT=0`` turns the
kernel off as it does the DSP's.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from functools import lru_cache
from typing import Any

#: samples of static beat phase before numba is loaded for this kernel alone: ~0.9 s of loading over
#: ~5 ns saved a sample (module docstring)
LOAD_AFTER_SAMPLES = 180_000_000
_asked = [0]        # samples asked for so far (a count; a race only delays the load)


@lru_cache(maxsize=1)
def _compiled() -> Callable[..., Any] | None:
    try:
        from sim_devices.world import synth_kernels  # needs numba
    except ImportError:
        return None
    return synth_kernels.static_fill


def _numba_loaded() -> bool:
    return "numba" in sys.modules


def static_fill(samples: int) -> Callable[..., Any] | None:
    """The compiled kernel, or None (numba missing, LIDARD_DSP_JIT=0, or not worth loading yet:
    module docstring; ``samples``: how many this call is about to fill)."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0":
        return None
    if _compiled.cache_info().currsize == 0 and not _numba_loaded():
        _asked[0] += int(samples)
        if _asked[0] < LOAD_AFTER_SAMPLES:
            return None
    return _compiled()
