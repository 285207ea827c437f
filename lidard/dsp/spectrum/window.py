"""Spectral windows for FMCW range processing (dissertation §2.1.1, eqs. 2-1..2-3).

The range FFT of a beat signal (eq. 2-1: d = c f_b / (2 gamma)) is taken over one chirp of
duration T, so its resolution is one FFT bin = 1/T (eq. 2-3).  The window trades main-lobe width
(resolution of two close targets) against side-lobe leakage (a weak target next to a strong one).
This module names the supported windows, builds them from their cosine-sum definitions (numpy: scipy.signal
costs about a second of every command's start-up; the samples are scipy.signal.get_window's) and derives
the figures the rest of the DSP chain needs from the window samples themselves (no tabulated numbers):

* ``enbw_bins``      equivalent noise bandwidth in bins, N sum(w^2) / sum(w)^2
* ``mainlobe_6db_bins``  full width of the main lobe at -6 dB (amplitude 1/2), in bins
* ``first_null_bins``    half-width of the main lobe to its first null, in bins
* ``leakage_envelope``   worst-case power leaked into a bin ``d`` bins away from a peak bin,
                         relative to that peak bin (used by CFAR to tell side-lobes from targets)

All windows are the periodic ("DFT-even") form, which is the right one for spectral analysis.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, get_args

import numpy as np


WindowName = Literal["rectangular", "hann", "blackmanharris"]
WINDOW_NAMES: tuple[str, ...] = get_args(WindowName)

#: Each window as a generalized cosine sum w[n] = sum_k (-1)^k a_k cos(2 pi k n / M): its coefficients
#: a_k. Hann: a raised cosine; Blackman-Harris: the minimum 4-term window of Harris (1978, Proc. IEEE
#: 66(1), table 1: -92 dB side lobes). One explicit table, no aliases.
COSINE_COEFFS: dict[str, tuple[float, ...]] = {
    "rectangular": (1.0,),
    "hann": (0.5, 0.5),
    "blackmanharris": (0.35875, 0.48829, 0.14128, 0.01168),
}


class DspInputError(ValueError):
    """Bad argument or bad samples given to a lidard.dsp function (names the offending value)."""


def check_window_name(window: str) -> str:
    if window not in COSINE_COEFFS:
        raise DspInputError(f"window={window!r} is not supported; choose one of {WINDOW_NAMES}")
    return window


@lru_cache(maxsize=64)
def _window_cached(window: str, n: int, symmetric: bool) -> np.ndarray:
    # periodic ("DFT-even"): the first n samples of the symmetric window of n + 1 (M = n); symmetric: M = n - 1
    phase = 2.0 * np.pi * np.arange(n) / (n - 1 if symmetric else n)
    w = np.zeros(n)
    for k, a in enumerate(COSINE_COEFFS[window]):
        w += (-1) ** k * a * np.cos(k * phase)
    w.setflags(write=False)
    return w


def get_window(window: str, n: int, *, symmetric: bool = False) -> np.ndarray:
    """(``window``: a :data:`WindowName`, checked here.) Periodic window of length ``n`` (read-only float64 array); ``symmetric``: the filter-design form
    (both ends equal), for windowing a segment that is not one period of a DFT."""
    check_window_name(window)
    if int(n) != n or n < 2:
        raise DspInputError(f"window length n={n!r} must be an integer >= 2")
    return _window_cached(window, int(n), bool(symmetric))


def window_dtft(w: np.ndarray, u_bins: np.ndarray) -> np.ndarray:
    """|W(u)| of window ``w`` at offsets ``u_bins`` (in bins of len(w)), normalised to W(0)=1."""
    n = np.arange(w.size)
    u = np.asarray(u_bins, dtype=np.float64)
    flat = u.ravel()
    out = np.empty(flat.size)
    step = max(1, 2_000_000 // w.size)  # bound the temporary (len(u) x n) phase matrix
    for i in range(0, flat.size, step):
        ph = np.exp(-2j * np.pi * np.outer(flat[i : i + step], n) / w.size)
        out[i : i + step] = np.abs(ph @ w)
    return (out / np.sum(w)).reshape(u.shape)


@dataclass(frozen=True)
class WindowInfo:
    """Figures of merit of a window of a given length, derived numerically from its samples."""

    name: str
    n: int
    coherent_gain: float  # mean(w): amplitude of an on-bin tone relative to the rectangular window
    enbw_bins: float  # equivalent noise bandwidth, bins
    mainlobe_6db_bins: float  # full main-lobe width at -6 dB (amplitude 0.5), bins
    first_null_bins: float  # main-lobe half-width to the first null, bins
    leakage_envelope: np.ndarray  # index d: worst-case |W|^2 at d bins from the peak bin / peak bin power


#: bins out from a peak that the leakage envelope covers (and so CFAR's side-lobe screen reads)
LEAKAGE_REACH_BINS = 64


@lru_cache(maxsize=64)
def window_info(window: WindowName, n: int, max_distance_bins: int = LEAKAGE_REACH_BINS) -> WindowInfo:
    """Compute (and cache) the :class:`WindowInfo` of ``window`` with ``n`` samples."""
    w = get_window(window, n)
    cg = float(np.mean(w))
    enbw = float(w.size * np.sum(w**2) / np.sum(w) ** 2)
    # Lobe shapes in bins converge quickly with n; past 1024 samples the difference is < 1e-6,
    # so evaluate the DTFT of a 1024-sample window to keep this cache cheap for long ramps.
    w = get_window(window, min(int(n), 1024))

    # -6 dB half-width: bisection on the monotonic part of the main lobe.
    lo, hi = 0.0, 4.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if window_dtft(w, np.array([mid]))[0] > 0.5:
            lo = mid
        else:
            hi = mid
    mainlobe_6db = 2.0 * lo

    # First null: first local minimum of |W(u)| on a fine grid.
    u = np.linspace(0.0, 8.0, 1601)
    mag = window_dtft(w, u)
    interior = np.flatnonzero((mag[1:-1] <= mag[:-2]) & (mag[1:-1] <= mag[2:])) + 1
    first_null = float(u[interior[0]]) if interior.size else 8.0

    # Leakage envelope: a tone at offset delta in [-0.5, 0.5] from its peak bin puts
    # |W(d - delta)|^2 into bin d and |W(delta)|^2 into the peak bin; take the worst delta.
    deltas = np.linspace(-0.5, 0.5, 101)
    dists = np.arange(max_distance_bins + 1, dtype=np.float64)
    num = window_dtft(w, dists[:, None] - deltas[None, :]) ** 2
    den = window_dtft(w, deltas) ** 2
    env = np.max(num / den[None, :], axis=1)
    env.setflags(write=False)
    return WindowInfo(
        name=window,
        n=int(n),
        coherent_gain=cg,
        enbw_bins=enbw,
        mainlobe_6db_bins=mainlobe_6db,
        first_null_bins=first_null,
        leakage_envelope=env,
    )
