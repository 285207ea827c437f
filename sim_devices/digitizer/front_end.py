"""The simulated digitizer's analog front end: anti-alias band limit, then the quantizer.

Split from :mod:`sim_devices.digitizer.device` (which re-exports these names); the response and the
quantizer are documented there and in docs/protocols/digitizer.md. Integer codes that no filter
touches at the record rate are quantized in integer arithmetic: the same codes as the
float path, in a few passes and without a float64 copy of every batch.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.digitizer import protocol as p


def butter(*args, **kwargs):
    # imported on first use: scipy.signal costs about a second of every command's start-up
    from scipy.signal import butter as fn
    return fn(*args, **kwargs)


def sosfiltfilt(*args, **kwargs):
    # imported on first use: scipy.signal costs about a second of every command's start-up
    from scipy.signal import sosfiltfilt as fn
    return fn(*args, **kwargs)


#: Butterworth order of the anti-alias filter, run forward and backward (zero phase, order doubles)
ANTI_ALIAS_ORDER = 4


def band_limit(x: np.ndarray, bandwidth_hz: float, sample_rate_hz: float) -> np.ndarray:
    """The anti-alias filter along the last axis (module docstring); float64 out.

    A corner of 0 or at/above fs/2 returns ``x`` unfiltered (as float64).
    """
    x = np.asarray(x, dtype=np.float64)
    if not 0 < bandwidth_hz < sample_rate_hz / 2 or x.shape[-1] < 2:
        return x
    n = ANTI_ALIAS_ORDER
    t_design = math.tan(math.pi * bandwidth_hz / sample_rate_hz) * (math.sqrt(2.0) - 1.0) ** (-1.0 / (2 * n))
    sos = butter(n, math.atan(t_design) * sample_rate_hz / math.pi, fs=sample_rate_hz, output="sos")
    # odd extension as long as the record allows: keeps the record ends free of start-up transients
    pad = min(x.shape[-1] - 1, 3 * (2 * len(sos) + 1))
    return sosfiltfilt(sos, x, axis=-1, padlen=pad)


def quantize_codes(x: np.ndarray, resolution_bits: int, format_bits: int) -> tuple[np.ndarray, int]:
    """Mid-tread quantizer of ``resolution_bits`` inside the ``format_bits`` container.

    Returns (codes as float64 multiples of the step 2**(format - resolution), highest code of the
    resolution). Values beyond full scale are left for the caller to clip and flag.
    """
    step = 1 << (format_bits - resolution_bits)
    hi = (1 << (format_bits - 1)) - step
    return np.round(np.asarray(x, dtype=np.float64) / step) * step, hi


def front_end(codes: np.ndarray, cfg: p.Config) -> tuple[np.ndarray, int]:
    """Band limit then quantize the source's codes (both channels alike); (codes, highest code)."""
    codes = np.asarray(codes)
    fs = float(cfg.sample_rate_hz)
    if codes.dtype.kind in "iu" and not 0 < float(cfg.bandwidth_hz) < fs / 2:
        # no filter at this rate (a corner at or above fs / 2): integer codes stay integers
        return quantize_int_codes(codes, cfg.resolution_bits, cfg.bits)
    x = band_limit(codes, float(cfg.bandwidth_hz), fs)
    return quantize_codes(x, cfg.resolution_bits, cfg.bits)


def _int16_top(resolution_bits: int) -> int:
    return (1 << 15) - (1 << (16 - resolution_bits))


def _quantizes_in_record(codes: np.ndarray, cfg: p.Config) -> bool:
    """int16 codes, 16-bit format at a lower resolution, no filter at this rate: quantized in int16
    straight into the record (:func:`quantize_int16_into`)."""
    return (codes.dtype == np.int16 and cfg.bits == 16 and cfg.resolution_bits < 16
            and not 0 < float(cfg.bandwidth_hz) < float(cfg.sample_rate_hz) / 2)


def quantize_int16_into(out: np.ndarray, codes: np.ndarray, resolution_bits: int) -> None:
    """``out[...] = clip(quantize(codes), -32768, top)`` for int16 codes in the 16-bit format, in
    int16 arithmetic (a few in-place passes, no int32 or float copy of a batch).

    The top code of the resolution, top = 32768 - step, is a multiple of the step, so a code above it
    quantizes to top or to 32768, which the converter clips to top: the result is quantize(min(codes,
    top)), whose sums stay below 32768 - step / 2 (no overflow); the bottom, -32768, is a code. The
    rounding is :func:`quantize_int_codes`'s (half to even), tested equal to :func:`quantize_codes`."""
    shift = 16 - resolution_bits
    top = _int16_top(resolution_bits)
    # blocks of records: the temporary stays small (in cache, and off the heap's high-water mark)
    per = max(1, _BLOCK_SAMPLES // max(1, int(np.prod(codes.shape[1:]))))
    for i in range(0, codes.shape[0], per):
        o = out[i:i + per]
        np.minimum(codes[i:i + per], top, out=o)
        _round_half_even_in_place(o, shift)


_BLOCK_SAMPLES = 1 << 16


def _round_half_even_in_place(q: np.ndarray, shift: int) -> None:
    """q -> the nearest multiple of step = 2**shift, ties to the even multiple (as ``np.round``), in place.

    q = m step + r: floor((q + step/2 - 1 + (m & 1)) / step) rounds r > step/2 up, r < step/2 down and
    r = step/2 to the even m (a few passes over the integers, no bool temporaries)."""
    odd = q >> shift
    odd &= 1
    q += (1 << (shift - 1)) - 1
    q += odd
    q >>= shift
    q <<= shift


def quantize_int_codes(codes: np.ndarray, resolution_bits: int, format_bits: int) -> tuple[np.ndarray, int]:
    """:func:`quantize_codes` of integer codes in integer arithmetic (the float64 round
    trip of every sample was most of the simulated transport's time). Same values: round half to
    even, as ``np.round`` does; int32 out, so codes beyond full scale survive for the clip."""
    step = 1 << (format_bits - resolution_bits)
    hi = (1 << (format_bits - 1)) - step
    if step == 1:
        return codes, hi
    q = codes.astype(np.int32)
    _round_half_even_in_place(q, format_bits - resolution_bits)
    return q, hi


def write_samples(out: np.ndarray, codes: np.ndarray, over: np.ndarray, cfg: p.Config) -> np.ndarray:
    """The converter's output for ``codes`` (count, n_channels, n) written into ``out`` (a record
    array's samples): band limit and quantizer (:func:`front_end`), clipped to the range of the
    resolution. Returns ``over`` (count, n_channels) with the clipped channels added."""
    lo, hi = (-128, 127) if cfg.bits == 8 else (-32768, 32767)
    if _quantizes_in_record(codes, cfg):
        quantize_int16_into(out, codes, cfg.resolution_bits)
        # over range where a row's largest code quantizes above the top (quantizing is monotone)
        top_q = quantize_int_codes(codes.max(axis=2).astype(np.int32), cfg.resolution_bits, 16)[0]
        return over | (top_q > _int16_top(cfg.resolution_bits))
    if cfg.bandwidth_hz or cfg.resolution_bits < cfg.bits:
        codes, hi = front_end(codes, cfg)
    sample_dt = p.sample_dtype(cfg.bits)
    if not ((lo, hi) == (np.iinfo(sample_dt).min, np.iinfo(sample_dt).max) and codes.dtype == sample_dt):
        # codes of the format's own type that may use all of it cannot be over range (no pass);
        # else a channel is over range when its extremes are (two reductions, no mask)
        clipped = (codes.max(axis=2) > hi) | (codes.min(axis=2) < lo)
        over = over | clipped
        if clipped.any():
            codes = np.clip(codes, lo, hi)
    out[...] = codes                           # cast on assignment: one pass
    return over
