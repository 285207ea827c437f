"""Directly modulated DFB laser: FM response to the AWG drive and Wiener phase noise.

Model (dissertation §2.1.3 (2), §2.2 and §2.3; presets in ``config/profiles/lasers.toml``, fields in
:class:`lidard.config.LaserPreset`)::

    nu(t) - nu0 = carrier * g(u)(t) + sum_k (h_k * g(u))(t),   g(u) = u + a2 u^2 + a3 u^3
    h_k: first-order low pass, H_k(s) = gain_k / (1 + s tau_k)

The instantaneous carrier term and the thermal terms have opposite signs (heating red-shifts a DFB),
which is what bends a plain triangular drive into the ~1 % nonlinear chirp of Fig. 2-4 (c, d) that
the iterative learning pre-distortion of §2.2 removes.

Discretisation. The AWG output is taken as the linear interpolation of its samples (first-order
hold): the response of each low pass to a piecewise-linear input is then exact at the sample
instants, y[n] = a y[n-1] + b0 x[n] + b1 x[n-1] with a = exp(-dt/tau). Because this is an exact
discrete LTI system, its periodic steady state follows *exactly* from one FFT of one drive period
(``frequency_hz``), and the causal response from rest (``frequency_hz_causal``, scipy lfilter with
the same coefficients) converges to it after many periods (a test checks this). Sampling the
continuous H(f) on the DFT grid instead would silently assume a band-limited drive, which a
triangle with sharp turning points is not; the two agree to O((dt/tau)^2).

Phase noise (§2.3, eqs. 2-14/2-15): a Wiener process whose increments over dt have variance
2 pi linewidth dt, linewidth = 1 / (pi tau_c), so Var[phi(t) - phi(t - tau)] = 2 tau / tau_c.
A laser with tau_c = inf has no phase noise and ``phase_noise_rad`` returns None without touching
the random generator (switched-off effects cost nothing).

Temperature: the preset describes the laser at its reference temperature. ``retuned``
gives the same laser with its carrier moved and its whole FM response scaled, which is what a TEC
temperature away from the reference does (the coefficients and their sources:
:mod:`sim_devices.world.tec`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lidard.config import LaserPreset
from lidard.physics.chirp import triangle_drive_v
from lidard.physics.constants import C_M_PER_S


def lfilter(*args, **kwargs):
    # imported on first use: scipy.signal costs about a second of every command's start-up
    from scipy.signal import lfilter as fn
    return fn(*args, **kwargs)


def _check_drive(drive_v, fs_hz: float, who: str) -> np.ndarray:
    u = np.asarray(drive_v, dtype=np.float64)
    if u.ndim != 1 or u.size < 2:
        raise ValueError(f"{who}: drive_v must be a 1-D array of >= 2 samples, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ValueError(f"{who}: drive_v contains NaN or inf")
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"{who}: fs_hz must be a positive finite rate, got {fs_hz!r}")
    return u


@dataclass(frozen=True)
class _Section:
    """Exact first-order-hold discretisation of gain / (1 + s tau) at sample period dt."""

    a: float
    b0: float
    b1: float

    @classmethod
    def make(cls, gain: float, tau_s: float, dt_s: float) -> _Section:
        x = dt_s / tau_s
        one_minus_a = -math.expm1(-x)
        a = 1.0 - one_minus_a
        r = one_minus_a / x              # tau (1 - a) / dt, -> 1 for tau >> dt
        return cls(a=a, b0=gain * (1.0 - r), b1=gain * (r - a))

    def response(self, z_inv: np.ndarray) -> np.ndarray:
        return (self.b0 + self.b1 * z_inv) / (1.0 - self.a * z_inv)


class DfbLaser:
    """A DFB laser defined by a :class:`~lidard.config.LaserPreset`.

    ``frequency_hz(drive, fs)`` gives nu(t) - nu0 for one period of a periodic drive;
    ``phase_noise_rad(n, dt, rng, shape=...)`` draws Wiener phase noise (None if linewidth is 0).
    """

    def __init__(self, preset: LaserPreset, *, nu0_offset_hz: float = 0.0, response_scale: float = 1.0) -> None:
        if not isinstance(preset, LaserPreset):
            raise TypeError(f"DfbLaser: preset must be a lidard.config.LaserPreset, got {type(preset).__name__}")
        if not math.isfinite(nu0_offset_hz):
            raise ValueError(f"DfbLaser: nu0_offset_hz must be finite, got {nu0_offset_hz!r}")
        if not (math.isfinite(response_scale) and response_scale > 0):
            raise ValueError(f"DfbLaser: response_scale must be finite and > 0, got {response_scale!r}")
        self.preset = preset
        self.nu0_offset_hz = float(nu0_offset_hz)      # carrier shift from the preset's (temperature)
        self.response_scale = float(response_scale)    # FM response relative to the preset's

    def retuned(self, *, nu0_offset_hz: float, response_scale: float) -> DfbLaser:
        """This laser with its carrier moved by ``nu0_offset_hz`` and its FM response (carrier and
        thermal terms alike) scaled by ``response_scale``, both relative to the preset."""
        return DfbLaser(self.preset, nu0_offset_hz=nu0_offset_hz, response_scale=response_scale)

    # -- properties --------------------------------------------------------------------------------
    @property
    def linewidth_hz(self) -> float:
        return self.preset.linewidth_hz

    @property
    def coherence_time_s(self) -> float:
        return self.preset.coherence_time_s

    @property
    def static_tuning_hz_per_v(self) -> float:
        """d nu / d u at DC for small drive (all thermal terms settled); negative for a DFB."""
        return self.response_scale * self.preset.static_tuning_hz_per_v

    @property
    def wavelength_m(self) -> float:
        return self.preset.wavelength_m

    @property
    def nu0_hz(self) -> float:
        """Optical carrier frequency c / lambda (the Doppler shift and the constant beat phase use it)."""
        return C_M_PER_S / self.preset.wavelength_m + self.nu0_offset_hz

    # -- FM response -------------------------------------------------------------------------------
    def static_nonlinearity(self, drive_v) -> np.ndarray:
        u = np.asarray(drive_v, dtype=np.float64)
        return u + self.preset.nonlin_a2 * u * u + self.preset.nonlin_a3 * u * u * u

    def _sections(self, fs_hz: float) -> list[_Section]:
        return [_Section.make(t.gain_hz_per_v, t.tau_s, 1.0 / fs_hz) for t in self.preset.thermal]

    def frequency_response(self, f_hz, fs_hz: float) -> np.ndarray:
        """Complex FM response (Hz/V of g(u)) of the discretised model at frequencies ``f_hz``."""
        z_inv = np.exp(-2j * np.pi * np.asarray(f_hz, dtype=np.float64) / fs_hz)
        h = np.full(z_inv.shape, complex(self.preset.carrier_hz_per_v))
        for s in self._sections(fs_hz):
            h = h + s.response(z_inv)
        return self.response_scale * h

    def frequency_hz(self, drive_v, fs_hz: float) -> np.ndarray:
        """Periodic steady state nu(t) - nu0 (Hz, float64) for one period of a periodic drive.

        ``drive_v[k]`` is the drive at t = k / fs_hz; the AWG repeats the waveform forever.
        """
        u = _check_drive(drive_v, fs_hz, "DfbLaser.frequency_hz")
        gu = self.static_nonlinearity(u)
        spec = np.fft.rfft(gu)
        f = np.fft.rfftfreq(u.size, d=1.0 / fs_hz)
        return np.fft.irfft(spec * self.frequency_response(f, fs_hz), n=u.size)

    def frequency_hz_causal(self, drive_v, fs_hz: float) -> np.ndarray:
        """Causal response from rest (laser at nu0, all thermal states 0) to ``drive_v`` as given.

        Not periodic: pass several repeated periods to watch the approach to the steady state.
        """
        u = _check_drive(drive_v, fs_hz, "DfbLaser.frequency_hz_causal")
        gu = self.static_nonlinearity(u)
        nu = self.preset.carrier_hz_per_v * gu
        for s in self._sections(fs_hz):
            nu = nu + lfilter([s.b0, s.b1], [1.0, -s.a], gu)
        return self.response_scale * nu

    # -- phase noise -------------------------------------------------------------------------------
    def phase_noise_rad(self, n: int, dt_s: float, rng: np.random.Generator, *, shape=()) -> np.ndarray | None:
        """Wiener phase noise, shape ``(*shape, n)``, increments of variance 2 pi linewidth dt.

        Returns None (and draws nothing) when the linewidth is 0.
        """
        if n < 0 or int(n) != n:
            raise ValueError(f"DfbLaser.phase_noise_rad: n must be a non-negative integer, got {n!r}")
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"DfbLaser.phase_noise_rad: dt_s must be positive and finite, got {dt_s!r}")
        return wiener_phase(self.linewidth_hz, int(n), dt_s, rng, shape=shape)


def wiener_phase(linewidth_hz: float, n: int, dt_s: float, rng: np.random.Generator, *, shape=()) -> np.ndarray | None:
    """Wiener phase phi[..., k] = sum_{i<=k} w_i, w_i ~ N(0, 2 pi linewidth dt); None if linewidth 0."""
    if linewidth_hz == 0.0:
        return None
    if not (math.isfinite(linewidth_hz) and linewidth_hz > 0):
        raise ValueError(f"wiener_phase: linewidth_hz must be >= 0 and finite, got {linewidth_hz!r}")
    shape = tuple(np.atleast_1d(shape).astype(int)) if shape != () else ()
    steps = rng.standard_normal((*shape, n))
    steps *= math.sqrt(2.0 * math.pi * linewidth_hz * dt_s)
    return np.cumsum(steps, axis=-1, out=steps)


def triangle_drive(excursion_hz: float, ramp_s: float, fs_hz: float, static_tuning_hz_per_v: float) -> np.ndarray:
    """One period of the plain triangular drive; the host's own :func:`lidard.physics.chirp.triangle_drive_v`."""
    return triangle_drive_v(excursion_hz, ramp_s, fs_hz, static_tuning_hz_per_v)


def ramp_nonlinearity_hz(nu_hz, n_ramp: int, roi: float = 0.8) -> tuple[float, float]:
    """RMS chirp nonlinearity (Hz) of the up and down ramps over the middle ``roi`` of each ramp.

    ``nu_hz`` is one period: samples [0, n_ramp) the up ramp, [n_ramp, 2 n_ramp) the down ramp.
    The best-fit line over the ROI is removed before taking the RMS (§2.2, Fig. 2-4).
    """
    nu = np.asarray(nu_hz, dtype=np.float64)
    if nu.ndim != 1 or nu.size != 2 * n_ramp:
        raise ValueError(f"ramp_nonlinearity_hz: nu_hz must be 1-D of 2*n_ramp = {2 * n_ramp} samples, got {nu.shape}")
    if not 0 < roi <= 1:
        raise ValueError(f"ramp_nonlinearity_hz: roi must be in (0, 1], got {roi!r}")
    skip = int(round(n_ramp * (1 - roi) / 2))
    out = []
    for ramp in (nu[:n_ramp], nu[n_ramp:]):
        seg = ramp[skip:n_ramp - skip]
        x = np.arange(seg.size, dtype=np.float64)
        fit = np.polyval(np.polyfit(x, seg, 1), x)
        out.append(float(np.sqrt(np.mean((seg - fit) ** 2))))
    return out[0], out[1]
