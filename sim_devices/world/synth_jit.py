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

With white noise on, the quantizer draws each record's noise in the same pass
(:func:`sim_devices.world.synth_kernels.noisy_quantize_rows`: the counter-based generator of
:mod:`sim_devices.world.gauss`, whose log and sine are polynomials, so the loops vectorize without a
vector libm, and numpy computes the same bits).

The beat's cosine stays in numpy: its float32 cosine is a SIMD loop (~0.7 ns a sample here) where a
compiled scalar libm cosine costs ~9 ns (measured on this 2-core EPYC).

Loading numba costs ``LOAD_CPU_S`` of CPU once per process; the static phase kernel saves ~5 ns a
sample and the noisy quantizer ~25 ns a noise sample (gauss' numpy path is ~30 ns a sample, the
kernel ~2), so the kernels are used when numba is already loaded in the process (the host's DSP
loads it for large scans, lidard.dsp.spectrum.jit) or once the savings this process has asked for
reach the loading cost (the break-even of that model); until then, and without numba, the numpy
path runs. ``LIDARD_DSP_JIT=0`` turns the kernels off as it does the DSP's.

A one-shot command knows its scan before its bench has started: :func:`load_ahead` starts the load on
a thread of its own when that scan alone passes the break-even, so that it runs while the command sets
up (the DSP's worker processes start in other processes meanwhile) instead of at the scan's first read,
which waits for it if it is not done.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import threading
from collections.abc import Callable
from functools import lru_cache
from typing import Any

#: CPU seconds of loading numba and the kernels once in a process (measured: ~0.9 s)
LOAD_CPU_S = 0.9
#: CPU seconds a compiled sample saves (module docstring): static beat phase, noise + quantization
SAVED_S_PHASE, SAVED_S_NOISE = 5e-9, 25e-9
#: samples of static beat phase before numba is loaded for this kernel alone (the break-even)
LOAD_AFTER_SAMPLES = int(LOAD_CPU_S / SAVED_S_PHASE)
_asked = [0.0]      # CPU seconds the kernels would have saved so far (a race only delays the load)
_loader: list[threading.Thread] = []      # load_ahead's thread, once per process
_loader_lock = threading.Lock()


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
def _quantizer() -> tuple[Callable[..., Any], Callable[..., Any]] | None:
    try:
        from sim_devices.world import synth_kernels  # needs numba
    except ImportError:
        return None
    return synth_kernels.quantize_rows, synth_kernels.noisy_quantize_rows


def _worth_it(samples: int, saved_s: float = SAVED_S_PHASE) -> bool:
    """Whether the kernels run for a call about to process ``samples``, each saving ``saved_s`` CPU
    seconds (module docstring)."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0":
        return False
    if _loader and _loader[0].is_alive():
        _loader[0].join()       # load_ahead's load is under way: the kernels are coming
    if not _numba_loaded() and _compiled.cache_info().currsize == 0:
        _asked[0] += int(samples) * saved_s
        if _asked[0] < LOAD_CPU_S:
            return False
    return True


def expect(samples: int) -> None:
    """An acquisition of ``samples`` noisy record samples was just armed (the simulated digitizer's
    ARM): their savings count toward the break-even now, so a scan that will pass it is synthesized
    compiled from its first read instead of after ~36 M samples on the numpy path (a 3,072-pixel
    region scan is about that size: all of it on the slower path)."""
    if os.environ.get("LIDARD_DSP_JIT", "1") != "0":
        _asked[0] += int(samples) * SAVED_S_NOISE


def load_ahead(samples: int) -> bool:
    """A scan of ``samples`` noisy record samples is coming (a one-shot command, before its bench
    arms): when they alone pass the break-even that :func:`expect` counts at the ARM, start
    :func:`load_now` on a thread now (module docstring). Nothing is counted here (the ARM counts the
    scan). Answers whether a load was started."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0" or int(samples) * SAVED_S_NOISE < LOAD_CPU_S:
        return False
    return start_load()


def start_load() -> bool:
    """Start :func:`load_now` on a thread of its own, once per process, whatever has been asked (a
    bench that will serve scans nobody has announced: a ``lidar-sim`` process, an embedded bench
    opened without a scan); a read that needs the kernels meanwhile waits for it (:func:`_worth_it`),
    and :func:`wait_loaded` joins it. Answers whether a load was started: not where numba is
    missing, ``LIDARD_DSP_JIT=0``, or the kernels are loading or loaded."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0":
        return False
    if "numba" not in sys.modules and importlib.util.find_spec("numba") is None:
        return False            # nothing to load: the numpy path runs
    with _loader_lock:
        if _loader or _reducer.cache_info().currsize:
            return False        # loading, or loaded
        t = threading.Thread(target=load_now, name="sim-jit-load", daemon=True)
        _loader.append(t)
        t.start()
    return True


def wait_loaded() -> None:
    """Wait for the load :func:`start_load` or :func:`load_ahead` started, if any."""
    if _loader:
        _loader[0].join()


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


def quantize_rows(samples: int, noisy: bool = False) -> Callable[..., Any] | None:
    """The compiled quantizer pass, or None, by the same rule: with ``noisy``, the one that draws the
    records' noise (synth_kernels.noisy_quantize_rows(v, keys, std, scale, lo, hi, out, over)),
    else synth_kernels.quantize_rows(v, noise, has_noise, scale, lo, hi, out, over)."""
    if not _worth_it(samples, SAVED_S_NOISE if noisy else SAVED_S_PHASE) or _compiled() is None:
        return None
    q = _quantizer()
    return None if q is None else q[1] if noisy else q[0]


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
