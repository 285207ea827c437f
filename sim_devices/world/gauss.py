"""White Gaussian noise for the digitizer records: a counter-based generator, float32 samples.

The additive noise of every record (shot + RIN + thermal + ambient, dissertation §2.4 eqs.
2-16..2-21, drawn in :mod:`sim_devices.world.synth_chunk`) is the largest single cost of a frame's
synthesis. It is drawn here as a pure function of (the stream's key, the record's index, the
channel, the sample's index): no generator state is carried from one record to the next, so a read
cut into parts on several threads (:mod:`sim_devices.world.synth_parallel`) gives the same records
as the read in one piece, and the compiled quantizer (:mod:`sim_devices.world.synth_kernels`) draws
each record's noise in the same pass that adds it and rounds it to codes (no noise array, no
separate pass).

Bits: SplitMix64 (Steele, Lea & Flood, OOPSLA 2014): word i of a record is the 64-bit finalizer
``mix64`` of ``key_r + (i + 1) * GAMMA``, ``key_r`` the record's key (:func:`record_keys`: the
stream key, record and channel through two finalizers). Its output passes BigCrush; records' keys are
64-bit hashes, so two records share a word only with probability ~ (words per record) / 2**64.

Gaussian (Box-Muller): sample pair j of a record takes words 2j and 2j+1. U = (w1 >> 11 + 1) / 2**53
in (0, 1], 53 bits: R = sqrt(-2 ln U) in float64 reaches sqrt(2 ln 2**53) = 8.6 sigma, so the tails
are not cut where any test or CFAR threshold looks. The angle is the top 24 bits of w2 (cell
midpoints: an angle moves a sample by < 4e-7 sigma). The two normals R cos(theta) and R sin(theta)
are independent; sample j of the record is the cosine, sample j + ceil(n / 2) the sine.

The transcendental functions are polynomials with a fixed order of float64 operations (no libm, no
fused multiply-add), so numpy (:func:`normal_rows`) and the compiled kernel give the same bits
(tests/sim_devices/world/test_synth_jit.py), and the compiled loops vectorize (numba has no vector
libm here: its scalar log and cos cost more than the whole kernel):

* ln U = e ln 2 + ln m with U = m 2**e, m in [sqrt(1/2), sqrt(2)) (exact split), and
  ln m = 2 atanh(s) = 2 s (1 + s^2/3 + ... + s^14/15), s = (m - 1) / (m + 1), |s| <= 0.1716:
  truncation < s^16 / 17 < 2e-14 relative to ln m;
* theta = q pi/2 + x, |x| <= pi/4 from the angle's integer (exact quadrant split); sin x and cos x
  by their Taylor series to x^11 and x^12: error < 1e-11.
Both are far below the float32 sample's rounding (6e-8 relative).

benchmarks/noise.py prints the cost against numpy's ziggurat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GAMMA = 0x9E3779B97F4A7C15                  # SplitMix64's increment (2**64 / golden ratio, odd)
MIX1, MIX2 = 0xBF58476D1CE4E5B9, 0x94D049BB133111EB   # its finalizer's multipliers
_MASK64 = (1 << 64) - 1

#: 2 / (2k + 1), k = 7 .. 0: ln m = s * (polynomial in s^2), Horner from the highest power
LOG_COEF = tuple(2.0 / (2 * k + 1) for k in range(7, -1, -1))
LN2 = math.log(2.0)
SQRT2 = math.sqrt(2.0)
#: (-1)^k / (2k)!, k = 6 .. 0 (cos) and (-1)^k / (2k + 1)!, k = 5 .. 0 (sin), Horner in x^2
COS_COEF = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(6, -1, -1))
SIN_COEF = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(5, -1, -1))
ANGLE_BITS = 24
ANGLE_STEP = 2.0 * math.pi / (1 << ANGLE_BITS)

#: channels of one record (each its own noise): the digitizer's four inputs
CHANNELS = ("beat", "beat_q", "mzi", "mzi_q")


def _mix64_int(z: int) -> int:
    z &= _MASK64
    z = ((z ^ (z >> 30)) * MIX1) & _MASK64
    z = ((z ^ (z >> 27)) * MIX2) & _MASK64
    return z ^ (z >> 31)


def mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finalizer of a uint64 array (a bijection of 64-bit words), in place."""
    z ^= z >> np.uint64(30)
    z *= np.uint64(MIX1)
    z ^= z >> np.uint64(27)
    z *= np.uint64(MIX2)
    z ^= z >> np.uint64(31)
    return z


def stream_key(*words: int) -> int:
    """A 64-bit stream key from integers (a seed, a run index ...): each word folded in through the
    finalizer, so keys of different word lists are unrelated."""
    k = 0
    for w in words:
        k = _mix64_int(k + _mix64_int(int(w) + GAMMA))
    return k


@dataclass(frozen=True)
class NoiseStream:
    """The white noise of a run of records: ``key`` (:func:`stream_key`) and the index of the first
    record synthesized (the bench: the read's first trigger)."""

    key: int
    first: int = 0

    def __post_init__(self) -> None:
        if not (0 <= int(self.key) < 1 << 64) or int(self.first) < 0:
            raise ValueError(f"NoiseStream: key must be a 64-bit word and first >= 0, got {self.key!r}, {self.first!r}")

    def shifted(self, records: int) -> NoiseStream:
        """The stream of a read starting ``records`` records later."""
        return NoiseStream(self.key, self.first + int(records))

    @classmethod
    def from_rng(cls, rng: np.random.Generator) -> NoiseStream:
        """A stream keyed by one 64-bit draw of ``rng``."""
        return cls(int(rng.integers(0, 1 << 64, dtype=np.uint64)))


def record_keys(stream: NoiseStream, start: int, count: int, channel: str) -> np.ndarray:
    """The keys (uint64) of records ``stream.first + start ..`` (``count`` of them) on ``channel``."""
    c = CHANNELS.index(channel)
    idx = np.arange(stream.first + start, stream.first + start + count, dtype=np.uint64)
    z = idx * np.uint64(len(CHANNELS)) + np.uint64(c + 1)
    z *= np.uint64(GAMMA)
    z += np.uint64(int(stream.key))
    return mix64(mix64(z))


def _words(keys: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """(w1, w2) (rows, h): words 2j and 2j + 1 of each record's SplitMix64 sequence."""
    step = np.arange(1, 2 * h + 1, 2, dtype=np.uint64) * np.uint64(GAMMA)
    w1 = keys[:, None] + step[None, :]
    w2 = w1 + np.uint64(GAMMA)
    return mix64(w1), mix64(w2)


def _radius(w1: np.ndarray, std: np.ndarray) -> np.ndarray:
    """sqrt(-2 ln U) * std (float64) of U = ((w1 >> 11) + 1) / 2**53 (module docstring)."""
    f = ((w1 >> np.uint64(11)).astype(np.int64) + 1).astype(np.float64)
    m, e = np.frexp(f)                   # f = m 2**e, m in [0.5, 1): exact
    m *= 2.0
    ef = (e - 54).astype(np.float64)     # U = (2m) 2**(e - 1 - 53)
    big = m > SQRT2
    np.multiply(m, 0.5, out=m, where=big)
    np.add(ef, 1.0, out=ef, where=big)
    s = (m - 1.0) / (m + 1.0)
    z = s * s
    p = np.full_like(z, LOG_COEF[0])
    for c in LOG_COEF[1:]:
        p *= z
        p += c
    lnu = ef * LN2 + s * p
    lnu *= -2.0
    r = np.sqrt(lnu, out=lnu)
    r *= std[:, None]
    return r


def _cos_sin(w2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin (float64) of theta from the top ANGLE_BITS of w2 (module docstring)."""
    a = (w2 >> np.uint64(64 - ANGLE_BITS)).astype(np.int64)
    qq = (a + (1 << (ANGLE_BITS - 3))) >> (ANGLE_BITS - 2)
    t = a - (qq << (ANGLE_BITS - 2))
    q = qq & 3
    x = (t.astype(np.float64) + 0.5) * ANGLE_STEP
    z = x * x
    cs = np.full_like(z, COS_COEF[0])
    for c in COS_COEF[1:]:
        cs *= z
        cs += c
    sn = np.full_like(z, SIN_COEF[0])
    for c in SIN_COEF[1:]:
        sn *= z
        sn += c
    sn *= x
    odd = (q & 1) == 1
    c1 = cs.copy()
    np.copyto(c1, sn, where=odd)
    s1 = sn
    np.copyto(s1, cs, where=odd)
    np.negative(c1, out=c1, where=(q == 1) | (q == 2))
    np.negative(s1, out=s1, where=q >= 2)
    return c1, s1


def normal_rows(keys: np.ndarray, n: int, std: np.ndarray | float = 1.0) -> np.ndarray:
    """The noise (float32, (rows, n)) of the records of ``keys`` (:func:`record_keys`), of standard
    deviation ``std`` (scalar or per row; it multiplies the float64 radius)."""
    keys = np.asarray(keys, dtype=np.uint64).reshape(-1)
    sd = np.broadcast_to(np.asarray(std, dtype=np.float64), keys.shape)
    out = np.empty((keys.size, n), dtype=np.float32)
    h = (n + 1) // 2
    if n == 0:
        return out
    rows = max(1, (1 << 14) // h)         # ~16 k pairs at a time: the temporaries stay in cache
    for r0 in range(0, keys.size, rows):
        r1 = min(keys.size, r0 + rows)
        w1, w2 = _words(keys[r0:r1], h)
        r = _radius(w1, sd[r0:r1])
        c, s = _cos_sin(w2)
        np.multiply(r, c, out=c)
        np.multiply(r, s, out=s)
        out[r0:r1, :h] = c
        out[r0:r1, h:] = s[:, :n - h]
    return out


def standard_normal_f32(rng: np.random.Generator, shape, scale: float = 1.0) -> np.ndarray:
    """Independent normal samples of ``shape``, float32, of standard deviation ``scale``: the rows
    of a stream keyed by one draw of ``rng`` (reproducible for the same generator state)."""
    shape = tuple(np.atleast_1d(shape).astype(int)) if np.ndim(shape) else (int(shape),)
    n = shape[-1] if shape else 1
    rows = int(np.prod(shape[:-1])) if len(shape) > 1 else 1
    keys = record_keys(NoiseStream.from_rng(rng), 0, rows, "beat")
    return normal_rows(keys, n, float(scale)).reshape(shape)
