"""Optional compiled kernels of the detection chain (numba, fused passes over the spectra, loaded only
where numba is installed); the numpy code they replace stays the reference and the fallback.

Each kernel gives the same values, bit for bit, as the numpy code it stands in for (tested in
tests/dsp/spectrum/test_dsp_jit.py): the same IEEE operations in the same order, no fast-math, and order
statistics are selections (the k-th smallest of a set is one of its elements whatever the method).
They exist because numpy makes one pass over the whole array per operation: the OS-CFAR screen of
:mod:`lidard.dsp.detect.os_cfar` took about a dozen passes over every spectrum cell, here it is one, which
also checks the values and finds each ramp's strongest cell (the detector's floor). The kernels
themselves are in :mod:`lidard.dsp.spectrum._kernels` (which imports numba); this module holds their callers.
The tone-model fits' kernels (:mod:`lidard.dsp.spectrum._kernels_fit`: the joint refinement's iteration,
the model-order test's and the skirt search's least squares) are the exception: a solve in plain loops
and the C library's sines give their values to rounding, not bit for bit (tests/dsp/spectrum/test_dsp_jit_fit.py);
their window grid is bit for bit.

numba is imported on first use, never at import time (``lidarctl --help`` and a scan's imports stay
fast), and only if it is installed (a dependency wherever numba publishes wheels: the
marker in pyproject.toml); :func:`kernels` returns None otherwise and the callers take their numpy path. ``LIDARD_DSP_JIT=0`` in the environment turns
the kernels off (for comparing the two paths; the results do not depend on it).

Loading numba and the cached kernels costs about 0.9 s of CPU once per process, and the kernels save
a few ns per spectrum cell (1-10 ns measured on this 2-core Xeon, benchmarks/band_and_cores.py): a
small scan pays more to load them than they save. So the DSP's own calls say how many cells they are
about to process (``kernels(cells)``) and numba is loaded only once the process has asked for
``LOAD_AFTER_CELLS`` of them; until then those calls take the numpy path (the same values).
A call without a count (tests, tools, :func:`decide`) loads it at once.
"""

from __future__ import annotations

import os
from functools import lru_cache
from types import SimpleNamespace

import numpy as np


#: Spectrum cells the DSP processes before numba is loaded: its ~0.9 s load over a saving of ~10 ns a
#: cell at best (the model of the module docstring), so a scan that processes fewer never loads it.
LOAD_AFTER_CELLS = 1 << 26
_asked = [0]        # cells asked for so far in this process (a count; races only delay the load)


@lru_cache(maxsize=1)
def _compiled() -> SimpleNamespace | None:
    try:
        from lidard.dsp.spectrum import _kernels as jit_kernels  # needs numba
        from lidard.dsp.spectrum import _kernels_fit as fit_kernels
    except ImportError:
        return None
    return SimpleNamespace(os_scan=jit_kernels.os_scan, power=jit_kernels.power, widths_6db=jit_kernels.widths_6db,
                           bin_table=jit_kernels.bin_table, newton_real_step=jit_kernels.newton_real_step,
                           real_slopes=jit_kernels.real_slopes,
                           joint_stencil=fit_kernels.joint_stencil,
                           order_fit=fit_kernels.order_fit, residual_fit=fit_kernels.residual_fit,
                           window_grid=fit_kernels.window_grid)


def kernels(cells: int | None = None) -> SimpleNamespace | None:
    """The compiled kernels, or None (numba missing, or LIDARD_DSP_JIT=0, or not loaded yet while this
    process has asked for fewer than LOAD_AFTER_CELLS cells, counting ``cells``)."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0":
        return None
    if cells is not None and _compiled.cache_info().currsize == 0:
        _asked[0] += int(cells)
        if _asked[0] < LOAD_AFTER_CELLS:
            return None
    return _compiled()


def decide() -> bool:
    """Settle this process's DSP path now, before a job's first batch: the compiled kernels loaded where
    they can be (True), else numpy for good (False); every later call takes that path.

    The cell count above lets a small scan skip numba's load, but it makes the path depend on the work the
    process did before, and the tone fits' kernels agree with numpy only to rounding (module docstring):
    enough to move a float32 point's last bit now and then (2 of 1,744 points' velocities in a 10 m/s
    region replay). A job whose results must depend on its input and its settings only (a raw capture's
    replay, a sweep task) calls this first: it then takes the path the DSP pool's workers take (they
    load the kernels at start, lidard.dsp_pool_preload) in every process and on every worker count."""
    return kernels() is not None


def power(spec: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """|X|^2 = re^2 + im^2 of a complex spectrum (float64), one pass (numpy: three); ``out``: a
    C-contiguous float64 array of the spectrum's shape to write it into (the same values)."""
    s = np.asarray(spec)
    k = kernels(s.size)
    if k is None or s.dtype != np.complex128 or s.size == 0:
        if out is None:
            return s.real ** 2 + s.imag ** 2
        np.multiply(s.real, s.real, out=out)
        out += s.imag ** 2
        return out
    if out is None:
        out = np.empty(s.shape)
    k.power(np.ascontiguousarray(s).reshape(-1), out.reshape(-1))
    return out


def widths_6db(flat: np.ndarray, start: np.ndarray, col: np.ndarray, n: int, max_half: int,
               kern: SimpleNamespace) -> np.ndarray:
    """lidard.dsp.detect._post._widths_flat's -6 dB widths, one peak after another (no pass per offset)."""
    out = np.empty(col.shape)
    kern.widths_6db(np.ascontiguousarray(flat, dtype=np.float64), np.ascontiguousarray(start, dtype=np.int64),
                    np.ascontiguousarray(col, dtype=np.int64), n, max_half, out)
    return out


def os_screen(p: np.ndarray, n_ref_side: int, n_guard: int, k_rank: int, thr_factor: float, mean_kth: float,
              kern: SimpleNamespace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, bins, noise) of the local maxima of ``p`` (rows, n) that may pass OS-CFAR, with the
    exact statistic (k-th smallest of the reference cells, mirrored at the edges, / ``mean_kth``).

    A local maximum c is kept when at least ``k_rank`` of its reference cells lie below
    p[c] * ``thr_factor`` (a necessary condition of the detector's test, see os_cfar._os_screened)."""
    found = _scan(kern, p, n_ref_side, n_guard, k_rank, thr_factor, mean_kth, 0.0, 0.0, False)
    assert found is not None        # only the exact pass checks the values (and may refuse them)
    return found


def os_detect(p: np.ndarray, n_ref_side: int, n_guard: int, k_rank: int, thr_factor: float, mean_kth: float,
              scaled_alpha: float, floor_factor: float,
              kern: SimpleNamespace) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(rows, bins, noise) of the cells of ``p`` (rows, n) that OS-CFAR detects, row-major: the local
    maxima with p > ``scaled_alpha`` * noise, noise > 0 and p > ``floor_factor`` times the row's
    largest cell, noise as in :func:`os_screen`; None if ``p`` holds a NaN, an infinite or a negative
    value (the caller names it). os_cfar._os_screened's decisions and the detector's test in one pass
    over the spectra, with a screen per block of cells first (lidard.dsp.spectrum._kernels)."""
    return _scan(kern, p, n_ref_side, n_guard, k_rank, thr_factor, mean_kth, scaled_alpha, floor_factor, True)


def _scan(kern: SimpleNamespace, p: np.ndarray, n_ref_side: int, n_guard: int, k_rank: int, thr_factor: float,
          mean_kth: float, scaled_alpha: float, floor_factor: float,
          exact: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    p = np.ascontiguousarray(p, dtype=np.float64)
    cap = max(1024, 4 * p.shape[0])
    while True:
        r = np.empty(cap, np.int64)
        c = np.empty(cap, np.int64)
        noise = np.empty(cap)
        m = kern.os_scan(p, p.view(np.int64), n_ref_side, n_guard, k_rank, thr_factor, mean_kth, scaled_alpha,
                         floor_factor, exact, r, c, noise)
        if m == -2:
            return None
        if m >= 0:
            return r[:m], c[:m], noise[:m]
        cap *= 4    # more cells than room: again with more (rare: a spectrum full of strong peaks)
