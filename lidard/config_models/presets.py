"""Scanner profile and laser preset models (``config/profiles/*.toml``, ``config/profiles/lasers.toml``).

A *profile* is one FPSA of dissertation §4.2 or §4.3 with its lenses, switch dynamics (§4.3.2) and the
Table 4-4 losses; a *laser preset* is a directly modulated DFB's FM response and noise (§2.2, Table 2-2).
Loaded by :func:`lidard.config.load_profile` / :func:`lidard.config.load_laser`; re-exported by
:mod:`lidard.config`.
"""

from __future__ import annotations

import math

from pydantic import Field, model_validator

from ..errors import ConfigError
from ..physics.optics import FpsaOptics, bonded_rows_skip
from .base import NonNegFloat, PosFloat, _Model


# --------------------------------------------------------------------------------------------------
# Scanner profile (FPSA + lenses + switch dynamics + losses)
# --------------------------------------------------------------------------------------------------
class Lens(_Model):
    focal_m: PosFloat
    f_number: PosFloat
    description: str = ""

    @property
    def aperture_m(self) -> float:
        """Entrance pupil diameter f / N."""
        return self.focal_m / self.f_number


class SwitchTiming(_Model):
    """Optical response times of one switch type (10-90 % of the optical transmission)."""

    on_s: PosFloat
    off_s: PosFloat


class BondedRows(_Model):
    """Which row lines are wire-bonded: all, or all but one in every ``skip_every`` (§4.3.3)."""

    skip_every: int = Field(default=0, ge=0)
    skip_offset: int = Field(default=3, ge=0)


class FpsaLosses(_Model):
    """One-way optical losses of the beam scanner (Table 4-4), dB."""

    fiber_coupling_db: NonNegFloat
    waveguide_db: NonNegFloat
    row_switch_db: NonNegFloat
    col_switch_db: NonNegFloat
    antenna_db: NonNegFloat
    lens_db: NonNegFloat

    @property
    def total_db(self) -> float:
        return (self.fiber_coupling_db + self.waveguide_db + self.row_switch_db + self.col_switch_db
                + self.antenna_db + self.lens_db)


class Profile(_Model):
    name: str
    description: str = ""
    rows: int = Field(gt=0, le=1024)
    cols: int = Field(gt=0, le=1024)
    pitch_m: PosFloat
    emission_w_m: PosFloat
    bonded: BondedRows = BondedRows()
    actuation_v: PosFloat
    pull_in_v: PosFloat
    release_v: PosFloat
    #: 1-sigma switch-to-switch spread of pull-in and release (both move together), V (simulator)
    threshold_spread_v: NonNegFloat = 0.0
    #: HV583 output discharge time constant into an actuator: release delay rc*ln(V/V_release), s
    discharge_rc_s: NonNegFloat = 0.0
    row_switch: SwitchTiming
    col_switch: SwitchTiming
    lenses: dict[str, Lens]
    default_lens: str
    losses: FpsaLosses
    losses_improved: FpsaLosses | None = None

    @model_validator(mode="after")
    def _check(self) -> Profile:
        if self.default_lens not in self.lenses:
            raise ValueError(f"default_lens {self.default_lens!r} is not one of the lenses {sorted(self.lenses)}")
        if not self.release_v < self.pull_in_v <= self.actuation_v:
            raise ValueError("need release_v < pull_in_v <= actuation_v (electrostatic pull-in hysteresis)")
        return self

    @property
    def bonded_rows(self) -> tuple[int, ...]:
        return bonded_rows_skip(self.rows, self.bonded.skip_every, self.bonded.skip_offset)

    def optics(self, lens: str | None = None, wavelength_m: float = 1.55e-6) -> FpsaOptics:
        name = lens or self.default_lens
        if name not in self.lenses:
            raise ConfigError(f"profile {self.name}: lens {name!r} unknown; allowed: {', '.join(sorted(self.lenses))}")
        return FpsaOptics(rows=self.rows, cols=self.cols, pitch_m=self.pitch_m,
                          emission_w_m=self.emission_w_m, focal_m=self.lenses[name].focal_m,
                          bonded_rows=self.bonded_rows, wavelength_m=wavelength_m)


# --------------------------------------------------------------------------------------------------
# Laser presets
# --------------------------------------------------------------------------------------------------
class ThermalTerm(_Model):
    """One thermal low-pass term of the DFB's FM response: gain (Hz per V of drive) and time constant."""

    gain_hz_per_v: float = Field(allow_inf_nan=False)
    tau_s: PosFloat


class LaserPreset(_Model):
    """A directly modulated DFB laser's FM response to the drive voltage u(t) and its noise.

    nu(t) - nu_0 = carrier_hz_per_v * g(u)(t) + sum_k (h_k * g(u))(t), with the static tuning
    nonlinearity g(u) = u + nonlin_a2 u^2 + nonlin_a3 u^3 and first-order low-pass thermal responses
    h_k of gain gain_hz_per_v and time constant tau_s. Thermal gains have the opposite sign to the
    carrier term (heating red-shifts a DFB), so the net static tuning is usually negative.
    Phase noise: Wiener process with linewidth = 1 / (pi coherence_time_s) (Table 2-2: 0.64 us).
    """

    description: str = ""
    wavelength_m: PosFloat = 1.55e-6
    carrier_hz_per_v: float = Field(allow_inf_nan=False)
    thermal: list[ThermalTerm] = []
    nonlin_a2: float = Field(default=0.0, allow_inf_nan=False)
    nonlin_a3: float = Field(default=0.0, allow_inf_nan=False)
    coherence_time_s: float = Field(default=0.64e-6, gt=0)  # inf = ideal laser
    rin_db_per_hz: float = Field(default=-150.0, le=0, allow_inf_nan=False)
    #: the laser's absolute maximum drive current: caps the controller's current limit
    #: (instrument.compose) and a devices.controller.laser_current_ma above it is refused at load
    max_current_ma: PosFloat = 200.0

    @property
    def linewidth_hz(self) -> float:
        return 0.0 if math.isinf(self.coherence_time_s) else 1.0 / (math.pi * self.coherence_time_s)

    @property
    def static_tuning_hz_per_v(self) -> float:
        return self.carrier_hz_per_v + sum(t.gain_hz_per_v for t in self.thermal)
