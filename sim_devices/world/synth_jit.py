"""The static beat phase of :mod:`sim_devices.world.synth_grid` as one compiled pass (numba, optional).

:func:`sim_devices.world.synth_grid._fill` builds dPhi = G - f_h (H1 + f_h H2) - const with five numpy
passes over every (hit, sample) and a Python loop per residue and delay offset. The kernel here walks
each hit's record once, in sample order, with the same float64 operations in the same order (no
fast-math: no reassociation, no fused multiply-add), so it gives the numpy path's values bit for bit
(tests/sim_devices/world/test_synth_jit.py), and it runs without the GIL: the bench's synthesis
threads and the host's DSP threads proceed side by side.

The digitizer's quantizer (add the noise, scale to codes, round, flag and clip, store int16: six numpy
passes over the float32 record) is a second kernel, :func:`quantize_rows`, with the same float32
operations in the same order (the same codes and flags; tests/sim_devices/world/test_synth_jit.py), and
the float32 cosine's range reduction of a phase in cycles (three numpy passes) a third,
:func:`turns_to_radians_f32`.

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


@lru_cache(maxsize=1)
def _quantizer() -> Callable[..., Any] | None:
    try:
        from sim_devices.world import synth_kernels  # needs numba
    except ImportError:
        return None
    return synth_kernels.quantize_rows


def _worth_it(samples: int) -> bool:
    """Whether the kernels run for a call about to process ``samples`` (module docstring)."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0":
        return False
    if _compiled.cache_info().currsize == 0 and not _numba_loaded():
        _asked[0] += int(samples)
        if _asked[0] < LOAD_AFTER_SAMPLES:
            return False
    return True


def static_fill(samples: int) -> Callable[..., Any] | None:
    """The compiled kernel, or None (numba missing, LIDARD_DSP_JIT=0, or not worth loading yet:
    module docstring; ``samples``: how many this call is about to fill)."""
    return _compiled() if _worth_it(samples) else None


def turns_to_radians_f32(samples: int) -> Callable[..., Any] | None:
    """The compiled range reduction of a phase in cycles (synth_kernels.turns_to_radians_f32), or None,
    by the same rule."""
    if not _worth_it(samples) or _compiled() is None:
        return None
    return _reducer()


@lru_cache(maxsize=1)
def _reducer() -> Callable[..., Any] | None:
    try:
        from sim_devices.world import synth_kernels  # needs numba
    except ImportError:
        return None
    return synth_kernels.turns_to_radians_f32


def quantize_rows(samples: int) -> Callable[..., Any] | None:
    """The compiled noise + quantizer pass (synth_kernels.quantize_rows), or None, by the same rule."""
    if not _worth_it(samples) or _compiled() is None:
        return None
    return _quantizer()


def load_now() -> bool:
    """Load numba and the compiled kernels now, whatever has been asked so far (module docstring), and
    run the range reduction once on a few samples, which starts numba's code generator (~60 MB the
    first compiled call adds to a process, on top of ~70 MB for the import).

    For a bench process that serves a daemon (``lidar-sim``): it passes the break-even within minutes
    of scanning (~180 M samples), so it would load numba anyway, only later, as one jump of its memory
    at a time that depends on the scans; loaded at its start, its memory is at its steady size from
    then on. False where numba is missing or ``LIDARD_DSP_JIT=0`` (nothing loaded)."""
    import numpy as np

    if os.environ.get("LIDARD_DSP_JIT", "1") == "0" or _compiled() is None:
        return False
    reduce = _reducer()
    if reduce is None:
        return False
    turns = np.linspace(-2.5, 2.5, 16)              # the types cos_sin passes: float64 in, float32 out
    reduce(turns, np.empty(turns.size, dtype=np.float32))
    return True
