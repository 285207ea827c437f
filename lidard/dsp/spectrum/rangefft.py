"""Range FFT of FMCW beat signals (dissertation §2.1.1, eqs. 2-1 and 2-3; §2.4 eq. 2-13).

A stationary target at distance d beats at f_b = 2 gamma d / c (eq. 2-1), so a spectrum of one
chirp is a range profile with range axis r = c f / (2 gamma) and bin spacing c fs / (2 gamma n_fft)
(eq. 2-3 for zero_pad = 1: c / (2 gamma T)).  :class:`RangeFFT` carries its own axes, like
``scipy.signal.ShortTimeFFT``: build it once per ramp geometry, call it on batches of ramps.

Conventions (documented once, used by the estimators and CFAR):

* The spectrum is ``fft(window * x, n_fft) / sum(window)``, so a real cosine of amplitude A puts
  |X| = A/2 in its bin and a complex exponential A exp(j 2 pi f t) puts |X| = A there.  The scale
  does not matter to CFAR (a ratio) and keeps spectra comparable across windows.
* Real input (a single photodiode): one-sided spectrum, bins 0 .. n_fft/2 (``np.fft.rfft`` layout).
* I/Q input (``iq=True``): two-sided spectrum, fft-shifted so that frequency increases with the
  index; bin numbers run from -n_fft/2 to n_fft/2 - 1 and negative frequencies are negative ranges
  (the sign of a beat is what resolves Doppler folding, §2.1.2).
* "Bin numbers" (``.bins``) are signed frequencies in units of ``delta_f``; indices into the
  spectrum array are converted with :meth:`RangeFFT.index_to_bin`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidard.dsp.spectrum.jit import power
from lidard.dsp.spectrum.scratch import scratch
from lidard.dsp.spectrum.window import DspInputError, WindowInfo, WindowName, check_window_name, get_window, window_info

C_M_PER_S = 299_792_458.0


def check_samples(x: object, n_samples: int | None = None, name: str = "x") -> np.ndarray:
    """Return ``x`` as a float64/complex128 array; raise DspInputError naming NaN/inf or bad shape."""
    a = np.asarray(x)
    if a.dtype.kind not in "biufc":
        raise DspInputError(f"{name} must be numeric, got dtype {a.dtype}")
    if a.ndim == 0:
        raise DspInputError(f"{name} must have at least one dimension (samples on the last axis)")
    if n_samples is not None and a.shape[-1] != n_samples:
        raise DspInputError(f"{name} has {a.shape[-1]} samples on its last axis, expected {n_samples}")
    a = a.astype(np.complex128 if a.dtype.kind == "c" else np.float64, copy=False)
    # one reduction: a sum is finite unless a sample is not (or the sum overflows: then the full map)
    with np.errstate(over="ignore", invalid="ignore"):
        total = np.add.reduce(a, axis=None) if a.size else 0.0
    if np.isfinite(total):
        return a
    finite = np.isfinite(a)
    if not finite.all():
        n_nan = int(np.count_nonzero(np.isnan(a)))
        n_inf = int(a.size - np.count_nonzero(finite) - n_nan)
        first = np.unravel_index(int(np.argmin(finite.ravel())), a.shape)
        raise DspInputError(
            f"{name} contains {n_nan} NaN and {n_inf} infinite sample(s); first at index {tuple(int(i) for i in first)}"
        )
    return a


def windowed_fft(x: np.ndarray, window: np.ndarray, n_fft: int, layout: str,
                 out: np.ndarray | None = None, power_out: np.ndarray | None = None) -> np.ndarray:
    """The one windowed FFT of the DSP (RangeFFT, the estimators, the compensated spectrum wrap it).

    ``layout``: "real" (rfft of a real ramp, bins 0..n_fft/2), "shifted" (two-sided fft of I/Q samples,
    fft-shifted so that frequency increases with the index), "analytic" (an analytic signal's fft,
    positive bins 0..n_fft/2 only: the rfft grid). Unscaled: the callers own the amplitude convention
    (a window may carry the scale). ``out``: a C-contiguous complex128 array of the spectrum's shape to
    write it into (a caller's scratch buffer); ``power_out``: the same for |X|^2 (float64), computed
    with the spectrum (:func:`lidard.dsp.spectrum.jit.power`'s values).

    The ramps go through in chunks of :data:`_CHUNK_BYTES`: a chunk's windowed
    product is still in cache when its FFT reads it, and its spectrum when its power is taken, where
    whole-batch passes went through memory three more times (~10 ms of ~45 per 20,000 ramps of 512).
    Every ramp is transformed alone either way: the values are those of one whole-batch call.
    """
    if layout not in ("real", "shifted", "analytic"):
        raise DspInputError(f"layout={layout!r}: expected 'real', 'shifted' or 'analytic'")
    n = x.shape[-1]
    if window.shape != (n,):
        raise DspInputError(f"window of shape {window.shape} for ramps of {n} samples")
    n_out = n_fft if layout == "shifted" else n_fft // 2 + 1
    shape = x.shape[:-1] + (n_out,)
    spec = _output(out, shape, np.complex128, "out")
    pw = None if power_out is None else _output(power_out, shape, np.float64, "power_out")
    x2 = x.reshape(-1, n)
    s2 = spec.reshape(-1, n_out)
    p2 = None if pw is None else pw.reshape(-1, n_out)
    rows = max(1, _CHUNK_BYTES // (16 * max(n, n_fft)))
    buf = scratch("windowed_fft.xw", (min(rows, x2.shape[0]), n), np.result_type(x, window))
    for i in range(0, x2.shape[0], rows):
        j = min(i + rows, x2.shape[0])
        xw = np.multiply(x2[i:j], window, out=buf[:j - i])
        if layout == "real":
            np.fft.rfft(xw, n=n_fft, axis=-1, out=s2[i:j])
        elif layout == "shifted":
            s2[i:j] = np.fft.fftshift(np.fft.fft(xw, n=n_fft, axis=-1), axes=-1)
        else:
            s2[i:j] = np.fft.fft(xw, n=n_fft, axis=-1)[:, :n_out]
        if p2 is not None:
            power(s2[i:j], out=p2[i:j])
    return spec


# one chunk of windowed_fft: its ramps at 16 B a sample within 2 MB (cache-sized). Measured (CPU, best of 5)
# at N = 512 / 2880 / 11900: 0.5-8 MB chunks all within 5 % of each other and 10-25 % faster than one
# pass over the whole batch; 128 KB chunks pay Python's per-call cost
_CHUNK_BYTES = 1 << 21


def _output(out: np.ndarray | None, shape: tuple[int, ...], dtype: type, name: str) -> np.ndarray:
    if out is None:
        return np.empty(shape, dtype)
    if out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise DspInputError(f"{name} must be a C-contiguous {np.dtype(dtype)} array of shape {shape}, "
                            f"got {out.dtype} {out.shape}")
    return out


def gather_bins(spec: np.ndarray, bins: np.ndarray, n_fft: int, iq: bool,
                rows: np.ndarray | None = None) -> np.ndarray:
    """Complex spectrum values at signed integer ``bins`` (broadcast against spec[..., :1]).

    Works for any integer bin, including beyond the edges: bins wrap modulo n_fft, and for a real
    signal's one-sided spectrum X[-k] = conj(X[k]) supplies the mirror half. ``rows``: ``spec`` is
    (M, n_bins) and row i of ``bins`` (m, j) reads spectrum row ``rows[i]`` (no copy of the rows).
    """
    b = np.mod(np.asarray(bins, dtype=np.int64), n_fft)
    if iq:
        idx = np.mod(b + n_fft // 2, n_fft)
        return _take(spec, idx, rows)
    mirror = b > n_fft // 2
    idx = np.where(mirror, n_fft - b, b)
    vals = _take(spec, idx, rows)
    return np.where(mirror, np.conj(vals), vals)


def _take(spec: np.ndarray, idx: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    if rows is None:
        return np.take_along_axis(spec, idx, axis=-1)
    return spec[np.asarray(rows)[:, None], idx]


@dataclass(frozen=True)
class RangeFFT:
    """Windowed, zero-padded range FFT with its own frequency and range axes.

    ``range_gate_m=(min_m, max_m)`` selects the bins kept by :meth:`gate` (on |range| for I/Q).
    """

    n_samples: int
    fs_hz: float
    chirp_rate_hz_per_s: float
    window: WindowName = "hann"
    zero_pad: int = 1
    iq: bool = False
    range_gate_m: tuple[float, float] | None = None
    _w: np.ndarray = field(init=False, repr=False, compare=False)
    _w_scaled: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if int(self.n_samples) != self.n_samples or self.n_samples < 8:
            raise DspInputError(f"n_samples={self.n_samples!r} must be an integer >= 8")
        if not (np.isfinite(self.fs_hz) and self.fs_hz > 0):
            raise DspInputError(f"fs_hz={self.fs_hz!r} must be a positive finite number")
        if not (np.isfinite(self.chirp_rate_hz_per_s) and self.chirp_rate_hz_per_s > 0):
            raise DspInputError(
                f"chirp_rate_hz_per_s={self.chirp_rate_hz_per_s!r} must be positive (use |gamma| for down-ramps)"
            )
        if int(self.zero_pad) != self.zero_pad or self.zero_pad < 1:
            raise DspInputError(f"zero_pad={self.zero_pad!r} must be an integer >= 1")
        check_window_name(self.window)
        if self.range_gate_m is not None:
            lo, hi = self.range_gate_m
            if not (0 <= lo < hi):
                raise DspInputError(f"range_gate_m={self.range_gate_m!r} must satisfy 0 <= min_m < max_m")
        object.__setattr__(self, "_w", get_window(self.window, self.n_samples))
        object.__setattr__(self, "_w_scaled", self._w / np.sum(self._w))

    # ---- axes -------------------------------------------------------------------------------
    @property
    def n_fft(self) -> int:
        return int(self.n_samples * self.zero_pad)

    @property
    def delta_f(self) -> float:
        """Bin spacing in Hz (fs / n_fft)."""
        return self.fs_hz / self.n_fft

    @property
    def delta_r(self) -> float:
        """Bin spacing in metres, c delta_f / (2 gamma); equals eq. 2-3 when zero_pad == 1."""
        return C_M_PER_S * self.delta_f / (2.0 * self.chirp_rate_hz_per_s)

    @property
    def resolution_m(self) -> float:
        """Two-target resolution c / (2 gamma T) (eq. 2-3) times the window's -6 dB lobe width."""
        return C_M_PER_S * self.fs_hz / (2.0 * self.chirp_rate_hz_per_s * self.n_samples) * self.info.mainlobe_6db_bins

    @property
    def bins(self) -> np.ndarray:
        """Signed bin number of every spectrum index."""
        if self.iq:
            return np.arange(-(self.n_fft // 2), self.n_fft - self.n_fft // 2)
        return np.arange(self.n_fft // 2 + 1)

    @property
    def freq_hz(self) -> np.ndarray:
        return self.bins * self.delta_f

    @property
    def range_m(self) -> np.ndarray:
        """c f / (2 gamma) for every spectrum index (negative for negative I/Q frequencies)."""
        return C_M_PER_S * self.freq_hz / (2.0 * self.chirp_rate_hz_per_s)

    @property
    def gate_mask(self) -> np.ndarray:
        r = np.abs(self.range_m)
        if self.range_gate_m is None:
            return np.ones(r.shape, dtype=bool)
        lo, hi = self.range_gate_m
        return (r >= lo) & (r <= hi)

    @property
    def info(self) -> WindowInfo:
        return window_info(self.window, self.n_samples)

    @property
    def window_samples(self) -> np.ndarray:
        return self._w

    def index_to_bin(self, index: np.ndarray) -> np.ndarray:
        return np.asarray(index) - (self.n_fft // 2 if self.iq else 0)

    def bin_to_index(self, bins: np.ndarray | int) -> np.ndarray:
        return np.asarray(bins) + (self.n_fft // 2 if self.iq else 0)

    def bin_to_range_m(self, bins: np.ndarray) -> np.ndarray:
        """Fractional bin numbers (e.g. from the estimators) to range in metres."""
        return C_M_PER_S * np.asarray(bins, dtype=np.float64) * self.delta_f / (2.0 * self.chirp_rate_hz_per_s)

    # ---- transforms -------------------------------------------------------------------------
    def __call__(self, x: object, out: np.ndarray | None = None, power_out: np.ndarray | None = None) -> np.ndarray:
        """Complex spectrum of a batch of ramps ``x[..., n_samples]`` (layout: module docstring).

        ``out``: a C-contiguous complex128 array of the spectrum's shape to write it into (a caller's
        scratch buffer, :mod:`lidard.dsp.spectrum.scratch`)."""
        return self.spectrum_of(check_samples(x, self.n_samples), out, power_out)

    def spectrum_of(self, a: np.ndarray, out: np.ndarray | None = None,
                    power_out: np.ndarray | None = None) -> np.ndarray:
        """:meth:`__call__` on ramps that went through :func:`check_samples` already (no second pass);
        ``power_out``: an array of the spectrum's shape (float64) that receives |X|^2 as well."""
        if a.dtype.kind == "c" and not self.iq:
            raise DspInputError("complex (I/Q) samples given to a RangeFFT built with iq=False; build it with iq=True")
        # the 1 / sum(w) scale rides on the window: no pass over the spectrum
        return windowed_fft(a, self._w_scaled, self.n_fft, "shifted" if self.iq else "real", out=out,
                            power_out=power_out)

    def spectrum_shape(self, lead: tuple[int, ...]) -> tuple[int, ...]:
        """The shape of the spectrum of ramps with leading shape ``lead``."""
        return tuple(lead) + ((self.n_fft,) if self.iq else (self.n_fft // 2 + 1,))

    def power(self, x: object, average_axis: int | None = None) -> np.ndarray:
        """|X|^2; with ``average_axis`` the powers of several chirps are averaged (incoherently)."""
        spec = self(x)
        p = spec.real**2 + spec.imag**2
        if average_axis is not None:
            if not -p.ndim <= average_axis < p.ndim or average_axis % p.ndim == p.ndim - 1:
                raise DspInputError(
                    f"average_axis={average_axis} must name a batch axis of x (ndim {p.ndim}), not the sample axis"
                )
            p = p.mean(axis=average_axis)
        return p

    def gate(self, values: np.ndarray) -> np.ndarray:
        """Keep the bins inside ``range_gate_m`` (last axis)."""
        return np.asarray(values)[..., self.gate_mask]
