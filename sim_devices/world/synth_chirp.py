"""The laser's deterministic chirp for beat synthesis: optical frequency and phase over one AWG
period (dissertation §2.1 eqs. 2-1..2-3; the laser model of ``sim_devices.world.laser``).

:class:`ChirpTrajectory` is computed once per AWG waveform on the AWG grid (:func:`trajectory` from
the laser model and its drive, :func:`trajectory_from_frequency` from a given nu(t)); the phase is
accumulated and evaluated in float64 and stored with its mean frequency removed, so that even
float64 never sees the ever-growing absolute phase of a long-running virtual clock (see the
precision note in ``sim_devices.world.synth``). Synthesis reads periodic phase samples from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lidard.physics.constants import C_M_PER_S
from sim_devices.world.laser import DfbLaser
from sim_devices.world.synth_types import SynthError


@dataclass(frozen=True)
class ChirpTrajectory:
    """The laser's deterministic optical frequency for one AWG period, and its phase.

    ``nu_hz[k]`` = nu(k / fs_hz) - nu0 (Hz), k = 0..N-1, periodic with ``period_s`` = N / fs_hz and
    linearly interpolated between samples (consistent with the laser model's first-order hold).
    ``phase_rad[k]`` = 2 pi int_0^{k/fs} (nu - nu0) dt for k = 0..N (float64, exact for the
    interpolated nu). ``nu0_hz`` = c / lambda enters through the Doppler term only.
    """

    fs_hz: float
    nu_hz: np.ndarray
    phase_rad: np.ndarray
    period_s: float
    nu0_hz: float
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def n(self) -> int:
        return int(self.nu_hz.size)

    @property
    def mean_hz(self) -> float:
        """Period average of nu - nu0 (the trapezoid mean of the interpolated nu)."""
        return float(self._tables()[3])

    def _tables(self):
        """Coefficients of the periodic phase (mean frequency removed), one quadratic per interval."""
        t = self._cache.get("tables")
        if t is None:
            nu = np.asarray(self.nu_hz, dtype=np.float64)
            mean = float(np.mean(nu))            # trapezoid mean of a periodic, linearly interpolated nu
            nup = nu - mean
            nxt = np.roll(nup, -1)
            dt = 1.0 / self.fs_hz
            c1 = 2.0 * np.pi * dt * nup
            c2 = np.pi * dt * (nxt - nup)
            # accumulate in the trajectory's dtype (float32 only in the precision test)
            acc_dtype = self.phase_rad.dtype
            c0 = np.zeros(nu.size, dtype=acc_dtype)
            np.cumsum((c1 + c2)[:-1].astype(acc_dtype), out=c0[1:], dtype=acc_dtype)
            t = (c0, c1.astype(acc_dtype), c2.astype(acc_dtype), mean)
            self._cache["tables"] = t
        return t

    def _tiled_turns(self, periods: int):
        """:meth:`_tiled` in cycles (each table / 2 pi), for the static fast path (synth_grid)."""
        return self._prefix("tiled_turns", periods,
                            lambda p: tuple(c * (1.0 / (2.0 * np.pi)) for c in self._tiled(p)))

    def _tiled(self, periods: int):
        def build(p: int):
            c0, c1, c2, _ = self._tables()
            return tuple(np.tile(c, p) for c in (c0, c1, c2))
        return self._prefix("tiled", periods, build)

    def _prefix(self, name: str, periods: int, build):
        """The tables tiled over ``periods`` periods, as views of the one longest tiling kept so far: a
        tiling over fewer periods is a prefix of it. One cache entry per name, not one per period count
        (a long-running bench sees many record lengths and range gates, each a new count)."""
        kept = self._cache.get(name)
        if kept is None or kept[0] < periods:
            kept = self._cache[name] = (periods, build(periods))
        if kept[0] == periods:
            return kept[1]
        n = periods * self.n
        return tuple(c[:n] for c in kept[1])

    def periodic_phase_samples(self, x, periods: int | None = None) -> np.ndarray:
        """Periodic phase (mean frequency removed) at AWG-sample positions ``x`` (float64 out).

        The arithmetic runs in the trajectory's dtype: float64, or float32 for the precision test,
        where both the sample position and the phase tables then carry float32 rounding.
        """
        dtype = self.phase_rad.dtype
        x = np.asarray(x, dtype=np.float64)
        n = self.n
        if periods is None:
            x = np.mod(x, n)
            periods = 1
        if dtype != np.float64:
            x = x.astype(dtype)
        c0, c1, c2 = self._tiled(periods)
        i = np.floor(x)
        f = x - i
        i = i.astype(np.intp)
        return (c0[i] + f * (c1[i] + f * c2[i])).astype(np.float64, copy=False)

    def _phase_nonneg(self, x: np.ndarray, periods: int) -> np.ndarray:
        """Hot path of ``periodic_phase_samples`` for float64 positions 0 <= x < periods * N.

        Consumes ``x`` (overwritten with the fractional part) and returns a new array.
        """
        if self.phase_rad.dtype != np.float64:
            return self.periodic_phase_samples(x, periods)
        c0, c1, c2 = self._tiled(periods)
        i = x.astype(np.intp)                  # truncation == floor for x >= 0
        x -= i
        # np.take: the same gather as c2[i], a third faster (no fancy-indexing set-up per call)
        out = np.take(c2, i)
        out *= x
        out += np.take(c1, i)
        out *= x
        out += np.take(c0, i)
        return out

    def phase_at(self, t_s) -> np.ndarray:
        """2 pi int_0^t (nu - nu0) dt' at arbitrary times (periodic extension of the period)."""
        t = np.asarray(t_s, dtype=np.float64)
        return self.periodic_phase_samples(t * self.fs_hz) + 2.0 * np.pi * self.mean_hz * t

    def frequency_at(self, t_s) -> np.ndarray:
        """nu(t) - nu0 at arbitrary times (linear interpolation, periodic)."""
        x = np.mod(np.asarray(t_s, dtype=np.float64) * self.fs_hz, self.n)
        i = np.floor(x).astype(np.intp)
        f = x - i
        nu = self.nu_hz
        return nu[i] + f * (nu[(i + 1) % self.n] - nu[i])


def trajectory(laser: DfbLaser, drive_v, fs_drive_hz: float, *, dtype=np.float64) -> ChirpTrajectory:
    """Compute the chirp of ``laser`` under one period of the periodic AWG waveform ``drive_v``.

    ``dtype`` exists for the precision test only (float32 shows why phases must be float64).
    """
    nu = laser.frequency_hz(drive_v, fs_drive_hz)
    return trajectory_from_frequency(nu, fs_drive_hz, nu0_hz=laser.nu0_hz, dtype=dtype)


def trajectory_from_frequency(nu_hz, fs_hz: float, *, nu0_hz: float = C_M_PER_S / 1.55e-6,
                              dtype=np.float64) -> ChirpTrajectory:
    """A :class:`ChirpTrajectory` from a given periodic nu(t) - nu0 (e.g. an ideal linear chirp)."""
    nu = np.asarray(nu_hz, dtype=np.float64)
    if nu.ndim != 1 or nu.size < 2 or not np.all(np.isfinite(nu)):
        raise SynthError(f"trajectory: nu_hz must be a finite 1-D array of >= 2 samples, got shape {nu.shape}")
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise SynthError(f"trajectory: fs_hz must be positive and finite, got {fs_hz!r}")
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise SynthError(f"trajectory: dtype must be float64 (or float32 for the precision test), got {dtype}")
    seg = (np.pi / fs_hz) * (nu + np.roll(nu, -1))       # trapezoid: exact for linear interpolation
    phase = np.zeros(nu.size + 1, dtype=dtype)
    np.cumsum(seg.astype(dtype), out=phase[1:], dtype=dtype)
    return ChirpTrajectory(fs_hz=float(fs_hz), nu_hz=nu, phase_rad=phase, period_s=nu.size / fs_hz,
                           nu0_hz=float(nu0_hz))
