"""The laser's true temperature and what it does to the chirp (dissertation §2.1.3, §2.2).

A DFB laser's optical frequency follows its chip temperature. The simulated bench models two effects
of a temperature ``dT = T_true - T_ref`` away from the reference at which the laser presets
(``config/profiles/lasers.toml``) describe the FM response (``REFERENCE_C`` = 25 C, the controller's
ambient and default set point):

* **carrier**: nu0 -> nu0 + ``tuning_hz_per_c`` dT. A DFB's Bragg wavelength moves with the
  refractive index, about +0.1 nm/C at 1550 nm, i.e. d nu / dT ~ -12 GHz/C (the sign is negative:
  warmer = redder). Typical DFB datasheet figure; ``[sim.tolerances] tec_tuning_hz_per_c``.
  It moves the constant beat phase 2 pi nu0 tau, not the beat frequency.
* **FM response**: the whole drive-to-frequency response (the carrier term and the thermal terms of
  :class:`~sim_devices.world.laser.DfbLaser`) scales by ``1 + response_per_c dT``. The tuning
  efficiency of a directly modulated DFB depends on temperature through the threshold current, the
  differential gain and the thermal impedance; a change of a few 0.1 %/C is our ESTIMATE (no measured
  figure for this laser: the dissertation does not give one), ``tec_response_per_c`` (default 0.2 %/C).
  A scaled response keeps a linearized chirp linear but changes its slope, so the excursion and every
  range measured with the stale drive change by the same factor: that is what the daemon's linearization
  health check (lidard.instrument.calibration.health) must catch.

The TEC holds its *thermistor* at the set point, and the controller reads that thermistor back, so
the daemon sees the set point (within the sensor's accuracy). The laser chip is not the thermistor:
a thermal gradient between them drifts with the ambient and the drive power. :class:`TecDrift` is
that offset, an Ornstein-Uhlenbeck process on the bench's VIRTUAL clock (rms ``tec_drift_c``,
correlation time ``tec_drift_period_s``), seeded, a pure function of time (the same at a given
virtual time whatever the order of queries). It starts at 0 when the bench starts (the laser has
just settled at its set point) and reaches its stationary rms after a few correlation times. A step
of the true temperature (fault ``tec_offset``, sim_devices.faults) is added on top, for tests.

The coefficients are the laser's physics, not a hidden assembly error, so they are taken as
configured (not drawn); the drift is the random part. ``[sim.tolerances] enabled = false`` or a
coefficient of 0 switches the effect off.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from .laser import DfbLaser

REFERENCE_C = 25.0          # the temperature at which the laser presets describe the FM response
QUANTUM_C = 1e-3            # the bench recomputes the chirp when the true temperature moves by this
_STEPS_PER_PERIOD = 64      # OU grid: period / 64, so linear interpolation changes its rms by < 1 %
_BLOCK = 256                # grid values drawn per seeded block


@dataclass(frozen=True)
class TecTuning:
    """How the chirp depends on the laser's true temperature (see the module docstring)."""

    tuning_hz_per_c: float = -12e9
    response_per_c: float = 0.0
    reference_c: float = REFERENCE_C

    def __post_init__(self) -> None:
        for name in ("tuning_hz_per_c", "response_per_c", "reference_c"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"TecTuning.{name} must be finite, got {getattr(self, name)!r}")

    @staticmethod
    def quantise(temperature_c: float) -> float:
        """``temperature_c`` on the 1 mK grid the bench's chirp cache keys on."""
        return round(float(temperature_c) / QUANTUM_C) * QUANTUM_C

    def laser_at(self, base: DfbLaser, temperature_c: float) -> DfbLaser:
        """``base`` (characterised at ``reference_c``) at the true temperature ``temperature_c``."""
        if not math.isfinite(temperature_c):
            raise ValueError(f"TecTuning.laser_at: temperature_c must be finite, got {temperature_c!r}")
        dt_c = float(temperature_c) - self.reference_c
        return base.retuned(nu0_offset_hz=self.tuning_hz_per_c * dt_c,
                            response_scale=1.0 + self.response_per_c * dt_c)


class TecDrift:
    """Ornstein-Uhlenbeck offset (C) of the laser chip from its thermistor, on the virtual clock.

    dx = -x dt / period + rms sqrt(2 / period) dW, x(t0) = 0. Values on a grid of period / 64 use
    the exact OU transition (x_{k+1} = a x_k + rms sqrt(1 - a^2) w_k, a = exp(-h / period)), drawn in
    blocks each seeded by (seed, block index); between grid points the value is interpolated linearly.
    """

    def __init__(self, rms_c: float, period_s: float, seed, *, t0_s: float = 0.0) -> None:
        if not (math.isfinite(rms_c) and rms_c >= 0):
            raise ValueError(f"TecDrift: rms_c must be finite and >= 0, got {rms_c!r}")
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"TecDrift: period_s must be finite and > 0, got {period_s!r}")
        self.rms_c, self.period_s, self.t0_s = float(rms_c), float(period_s), float(t0_s)
        self.step_s = self.period_s / _STEPS_PER_PERIOD
        self._seed = tuple(np.atleast_1d(seed).astype(np.int64).tolist())
        self._a = math.exp(-self.step_s / self.period_s)
        self._blocks: list[np.ndarray] = []   # grid values 1, 2, ... after x(t0) = 0
        self._lock = threading.Lock()   # the bench's capture thread and the controller's Modbus thread

    def _value(self, i: int) -> float:
        """Grid value i (0 at t0), drawing whole seeded blocks in order up to it."""
        if i == 0:
            return 0.0
        b, k = divmod(i - 1, _BLOCK)
        while len(self._blocks) <= b:
            w = np.random.default_rng((*self._seed, len(self._blocks))).standard_normal(_BLOCK)
            w *= self.rms_c * math.sqrt(1.0 - self._a * self._a)
            # a plain loop, not scipy.signal.lfilter: its first import costs about a second, which
            # the controller's Modbus thread would wait for (a block covers 256 grid steps)
            x = np.empty(_BLOCK)
            last = float(self._blocks[-1][-1]) if self._blocks else 0.0
            for j in range(_BLOCK):
                last = self._a * last + float(w[j])
                x[j] = last
            self._blocks.append(x)
        return float(self._blocks[b][k])

    def at(self, t_s: float) -> float:
        """The drift (C) at virtual time ``t_s``; 0 before the start. Thread-safe."""
        if self.rms_c == 0.0 or t_s <= self.t0_s:
            return 0.0
        k = (float(t_s) - self.t0_s) / self.step_s
        i = int(k)
        with self._lock:
            v0, v1 = self._value(i), self._value(i + 1)
        f = k - i
        return float((1.0 - f) * v0 + f * v1)


def from_tolerances(tol, seed: int) -> tuple[TecTuning | None, TecDrift | None]:
    """The bench's tuning and drift from ``[sim.tolerances]`` (``lidard.config.Tolerances``); None for
    an effect that is off. ``seed``: the bench's, used when the section gives none."""
    if not tol.enabled:
        return None, None
    tuning = None
    if tol.tec_tuning_hz_per_c != 0.0 or tol.tec_response_per_c != 0.0:
        tuning = TecTuning(tuning_hz_per_c=tol.tec_tuning_hz_per_c, response_per_c=tol.tec_response_per_c)
    drift = None
    if tol.tec_drift_c > 0.0:
        base = seed if tol.seed is None else tol.seed
        drift = TecDrift(tol.tec_drift_c, tol.tec_drift_period_s, (int(base), 0x7EC))
    return tuning, drift


__all__ = ["QUANTUM_C", "REFERENCE_C", "TecDrift", "TecTuning", "from_tolerances"]
