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
small scan pays more to load them than they save.

**A job's DSP path** (``"numpy"`` or ``"compiled"``, :data:`DspPath`) is decided once, before its first
batch, and every batch of the job takes it, on whichever thread or worker process runs it: the tone
fits' two paths differ in the last bits, so a job that switched part-way (or a replay that took the
other path) would not give the same points. The rule (:func:`plan_path`), from what the job will
process (the spectrum cells its calls will go over, :meth:`lidard.dsp.frame.FrameDsp.spectrum_cells`) and what is
already paid for:

* ``numpy`` where the kernels cannot run (numba not installed, ``LIDARD_DSP_JIT=0``);
* ``compiled`` where the load is already paid: the kernels are loaded in this process, or the job's
  batches go to the DSP pool's workers (they load the kernels at start, lidard.dsp_pool_preload);
* else the break-even: ``compiled`` once the cells of this process's jobs so far, this one's included,
  reach ``LOAD_AFTER_CELLS`` (the load is then worth it; the kernels are loaded at the decision, before
  the first batch), ``numpy`` below (a small one-shot scan never pays the load). A scan that records
  its raw segments counts one replay's cells too: its replays follow the path it takes.

The job then runs its DSP inside :func:`follow` (a thread-local setting: it never leaks into another
job on the same thread or pool); the path is recorded with the job's results (a scan's sidecar, its raw
capture), and a replay follows the recorded one (lidard.raw.replay). A call outside any job (tests,
tools) counts its cells as before: ``kernels(cells)`` loads numba once the process has asked for
``LOAD_AFTER_CELLS``, and a call without a count loads it at once. :func:`decide` settles the
compiled path where a job has no recorded path to follow (a sweep task; a capture older than the
recording of the path).
"""

from __future__ import annotations

import importlib.util
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from types import SimpleNamespace
from typing import Literal, get_args

import numpy as np


#: Spectrum cells the DSP processes before numba is loaded: its ~0.9 s load over a saving of ~10 ns a
#: cell at best (the model of the module docstring), so a scan that processes fewer never loads it.
LOAD_AFTER_CELLS = 1 << 26
_asked = [0]        # cells asked for so far in this process (a count; races only delay the load)

#: how a job's DSP runs: the numpy reference or the compiled kernels (module docstring)
DspPath = Literal["numpy", "compiled"]
DSP_PATHS: tuple[str, ...] = get_args(DspPath)
_job = threading.local()     # .path: the path of the job this thread runs (follow), None outside one


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


def _enabled() -> bool:
    return os.environ.get("LIDARD_DSP_JIT", "1") != "0"


def _past_break_even(cells: int) -> bool:
    """Count ``cells`` toward this process's total; whether it has reached LOAD_AFTER_CELLS."""
    _asked[0] += int(cells)
    return _asked[0] >= LOAD_AFTER_CELLS


def _loaded() -> bool:
    return _compiled.cache_info().currsize == 1 and _compiled() is not None


def installed() -> bool:
    """Whether this process can take the compiled path: numba installed and LIDARD_DSP_JIT not 0
    (without loading it)."""
    return _enabled() and (_loaded() or importlib.util.find_spec("numba") is not None)


def plan_path(cells: int, *, preloaded: bool = False) -> DspPath:
    """A job's DSP path, decided once before its first batch (the rule of the module docstring):
    ``cells``: the spectrum cells the job will process; ``preloaded``: its batches run where the
    kernels are loaded already (the DSP pool's workers). A compiled path decided here on the
    break-even loads the kernels now."""
    if cells < 0:
        raise ValueError(f"plan_path: cells must be >= 0, got {cells!r}")
    if not installed():
        return "numpy"
    if preloaded or _loaded():
        return "compiled"
    if not _past_break_even(cells):
        return "numpy"
    return "compiled" if _compiled() is not None else "numpy"


def check_path(path: object) -> DspPath:
    """``path`` if it names a DSP path, else a ValueError naming it."""
    if path not in DSP_PATHS:
        raise ValueError(f"DSP path {path!r} is not one of {', '.join(DSP_PATHS)}")
    return path     # type: ignore[return-value]


@contextmanager
def follow(path: DspPath | None) -> Iterator[None]:
    """Every DSP call of this thread inside the block takes ``path`` (None: the cell count of a call
    outside any job); the thread's setting before is put back after. ``compiled`` loads the kernels
    at the first call that wants them (numpy where this process has none: a caller that records the
    path checks :func:`installed` first)."""
    if path is not None:
        check_path(path)
    before = getattr(_job, "path", None)
    _job.path = path
    try:
        yield
    finally:
        _job.path = before


def kernels(cells: int | None = None) -> SimpleNamespace | None:
    """The compiled kernels, or None: numba missing, or LIDARD_DSP_JIT=0, or this thread's job follows
    the numpy path (:func:`follow`), or, outside a job, not loaded yet while this process has asked for
    fewer than LOAD_AFTER_CELLS cells, counting ``cells``."""
    if not _enabled():
        return None
    path = getattr(_job, "path", None)
    if path == "numpy":
        return None
    if path is None and cells is not None and _compiled.cache_info().currsize == 0 \
            and not _past_break_even(cells):
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
    load the kernels at start, lidard.dsp_pool_preload) in every process and on every worker count.
    A job that records its path decides it with :func:`plan_path` and runs inside :func:`follow`."""
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
