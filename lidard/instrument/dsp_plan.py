"""The signal path of a scan decided before the first trigger: ADC plan, phase-noise choice and the
frame DSP, built in ONE place for scans, streams and design sweeps (§2.1.1, §2.3, §4.4.3).

:func:`plan_signal` is the one constructor: from the resolved configuration, the request's range and
speed, and the calibration the daemon has learned (:class:`DspCalibration`: monitor delay, I/Q
imbalance, the held segment's measured drift) it sizes the ADC (:func:`adc_plan`: the rate from the
maximum range and Doppler band, the record with the chirp's constant segment), decides the monitor
channels, and builds the :class:`~lidard.dsp.frame.FrameDsp` (:func:`frame_dsp`). The scan loop
(:func:`lidard.instrument.scan_loop.plan_scan`) and a sweep task (:mod:`lidard.offline.sweep`) both
call it, so a sweep's statistics describe the DSP that scans run.

The constructor lives here, not on ``FrameDsp``: the DSP core is pure (numpy/scipy, no configuration
models: the import contract of ``lidard.dsp``), and the ADC plan is the instrument's. A raw capture's
replay does not call it either: it rebuilds the exact ``FrameDsp`` the scan built from the fields the
capture recorded (:meth:`lidard.dsp.frame.FrameDsp.from_record`), so that today's configuration cannot
change a capture's points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..config import Config
from ..dsp.ranging.estimators import DEFAULT_METHOD
from ..dsp.frame import FrameDsp
from ..dsp.detect.gate import decimation_gate
from ..dsp.spectrum.rangefft import C_M_PER_S
from ..physics.chirp import adc_rate_hz
from .errors import InstrumentError


@dataclass(frozen=True)
class AdcPlan:
    fs_hz: float
    ramp_samples: int
    record_length: int
    bits: int

    @property
    def cw_samples(self) -> int:
        """Samples of the chirp's constant-frequency segment in a record (0 on a triangle)."""
        return self.record_length - 2 * self.ramp_samples


@dataclass(frozen=True)
class DspCalibration:
    """What the DSP takes from the daemon's calibrations; :meth:`nominal` before any.

    ``mzi_delay_s``: the monitor MZI's effective delay (range calibration); ``iq_gain`` /
    ``iq_phase_rad``: the coherent receiver's imbalance (I/Q calibration); ``hold_profile``: the held
    segment's measured drift (:class:`lidard.dsp.ranging.cwhold.HoldProfile` as a dict; linearization)."""

    mzi_delay_s: float
    iq_gain: float = 1.0
    iq_phase_rad: float = 0.0
    hold_profile: dict | None = None

    @classmethod
    def nominal(cls, cfg: Config) -> DspCalibration:
        return cls(mzi_delay_s=float(cfg.monitor.delay_s))


@dataclass(frozen=True)
class SignalPlan:
    """The ADC plan, the monitor channels and the frame DSP of one scan (or one sweep task)."""

    adc: AdcPlan
    dsp: FrameDsp
    phase_noise: bool                   # the monitor MZI is recorded and the DSP compensates
    quadrature: bool                    # ... read in quadrature ("mzi_q", [monitor] quadrature)
    mzi_delay_s: float


def speed_span_mps(cfg: Config, max_speed_mps: float | None = None) -> float:
    """The Doppler the ADC band and the ramps' search cover: the scan's requested maximum speed, else
    the configuration's scan.max_speed_mps. On the three-segment chirp and the I/Q receiver the sign is
    measured: a band, not a prior; on a real triangle also the prior that makes a pair unambiguous."""
    v = cfg.scan.max_speed_mps if max_speed_mps is None else float(max_speed_mps)
    if not (math.isfinite(v) and v > 0):
        raise InstrumentError(f"scan: max_speed_mps must be a positive speed in m/s, got {max_speed_mps!r}")
    return v


def adc_plan(cfg: Config, max_range_m: float, *, whole_monitor_delay: bool = False,
             mzi_delay_s: float | None = None, max_speed_mps: float | None = None) -> AdcPlan:
    """Sample rate and record length for beats up to ``max_range_m`` plus the Doppler shift of
    ``max_speed_mps`` (default: the configuration's scan.max_speed_mps).

    ``whole_monitor_delay``: the quadrature reconstruction steps the laser phase by the monitor delay,
    so the rate is raised to a whole number of samples per delay (lidard.dsp.phasenoise.reconstruct.whole_delay_samples).
    """
    c, a = cfg.chirp, cfg.adc
    doppler = 2 * speed_span_mps(cfg, max_speed_mps) / c.wavelength_m
    fs = adc_rate_hz(max_range_m, c.rate_hz_per_s, max_doppler_hz=doppler, oversample=a.oversample,
                     max_rate_hz=a.max_sample_rate_hz, min_rate_hz=a.min_sample_rate_hz, ramp_s=c.ramp_s)
    if whole_monitor_delay:
        tau_m = cfg.monitor.delay_s if mzi_delay_s is None else mzi_delay_s
        fs = math.ceil(fs * tau_m - 1e-9) / tau_m
        if fs > a.max_sample_rate_hz:
            raise InstrumentError(f"scan: the quadrature monitor needs a whole number of samples per monitor delay "
                                  f"({tau_m:g} s): {fs / 1e6:.1f} MHz is above adc.max_sample_rate_hz")
    r = round(fs * c.ramp_s)
    # 16-bit records: the digitizer decimates its full-rate core on board (more bits at low rates);
    # a three-segment record also holds the constant segment (whole samples inside its cw_s)
    return AdcPlan(fs_hz=fs, ramp_samples=r, record_length=2 * r + int(fs * c.cw_s + 1e-9), bits=16)


def phase_noise_on(mode: str, max_range_m: float, mzi_delay_s: float) -> bool:
    """scan.phase_noise_compensation resolved: "auto" is on when the round trip of ``max_range_m`` is
    at least twice the monitor delay (config.ScanDefaults)."""
    if mode not in ("auto", "on", "off"):
        raise InstrumentError(f"scan: phase_noise_compensation={mode!r} is not one of 'auto', 'on', 'off'")
    if mode == "auto":
        return 2 * float(max_range_m) / C_M_PER_S >= 2 * mzi_delay_s
    return mode == "on"


def frame_dsp(cfg: Config, adc: AdcPlan, calibration: DspCalibration, *, max_range_m: float,
              max_speed_mps: float, estimator: str | None = None) -> FrameDsp:
    """The frame DSP of records sampled as ``adc`` plans them, for the configuration's chirp, receiver
    and detector settings (scan.window, scan.pfa, scan.max_returns) and the calibration's values.
    ``estimator``: the sub-bin estimator (default: the DSP's own; a sweep's ``dsp.estimator``)."""
    three = cfg.chirp.shape == "three_segment"
    return FrameDsp(ramp_samples=adc.ramp_samples, fs_hz=adc.fs_hz, chirp_rate_hz_per_s=cfg.chirp.rate_hz_per_s,
                    wavelength_m=cfg.chirp.wavelength_m, max_range_m=max_range_m,
                    max_speed_mps=max_speed_mps, window=cfg.scan.window, pfa=cfg.scan.pfa,
                    max_returns=cfg.scan.max_returns, cw_samples=adc.cw_samples,
                    iq=cfg.adc.iq, iq_gain=calibration.iq_gain, iq_phase_rad=calibration.iq_phase_rad,
                    hold_profile=calibration.hold_profile if three else None,
                    estimator=DEFAULT_METHOD if estimator is None else estimator, sfdr_dbc=cfg.adc.sfdr_dbc,
                    **decimation_gate(adc.fs_hz, cfg.adc.max_sample_rate_hz, cfg.adc.stopband_db,
                                      cfg.adc.input_range_v))


def plan_signal(cfg: Config, calibration: DspCalibration, *, max_range_m: float,
                max_speed_mps: float | None = None, phase_noise: str | None = None,
                estimator: str | None = None) -> SignalPlan:
    """The one constructor of a scan's signal path (module docstring). ``phase_noise``: the request's
    "auto" | "on" | "off" (default: scan.phase_noise_compensation)."""
    tau_m = float(calibration.mzi_delay_s)
    pn_on = phase_noise_on(phase_noise or cfg.scan.phase_noise_compensation, max_range_m, tau_m)
    quad = pn_on and cfg.monitor.quadrature
    speed = speed_span_mps(cfg, max_speed_mps)
    # the MZI beat (gamma tau_m) and its demodulation band (to 1.5 gamma tau_m) must be sampled too
    adc = adc_plan(cfg, max(max_range_m, 1.5 * C_M_PER_S * tau_m / 2) if pn_on else max_range_m,
                   whole_monitor_delay=quad, mzi_delay_s=tau_m, max_speed_mps=speed)
    dsp = frame_dsp(cfg, adc, calibration, max_range_m=max_range_m, max_speed_mps=speed, estimator=estimator)
    return SignalPlan(adc=adc, dsp=dsp, phase_noise=pn_on, quadrature=quad, mzi_delay_s=tau_m)
