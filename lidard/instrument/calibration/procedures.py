"""The calibration procedures over an instrument: measure plates, scan known targets, fit.

These run on whatever owns the instrument (the job worker's thread in the daemon, see
:mod:`lidard.jobs.calibrations`; a benchmark directly on an embedded bench). They take only the known
geometry as input: the plate's known distance, the targets' known poses. On a simulated bench the
caller places the targets through the scene first (``place``), as a lab does by hand.

Entry points for benchmarks (a :class:`lidard.instrument.facade.LidarInstrument`, no daemon):
:func:`run_range_calibration`, :func:`run_pointing_calibration` and :func:`run_iq_calibration`; each applies its fit to the
instrument (``use_calibrations``) and returns the linearization to scan with afterwards.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from dataclasses import dataclass
from typing import Any
from collections.abc import Callable, Sequence

import numpy as np

from ..dsp_plan import phase_noise_on
from ..types import CalibrationResult, ScanRequest
from .applied import AppliedCalibrations
from .iq import measure_iq, require_iq_receiver
from .pointing import PointingFit, Surface, fit_pointing, parse_geometry, scan_pixels, spheres_scene
from .range import DEFAULT_NOISE_M, CalibrationRefused, PlateMeasurement, RangeFit, fit_range, plate_measurement, plate_request, plate_scene

log = logging.getLogger(__name__)


def _scan(instrument, request: ScanRequest, linearization: CalibrationResult) -> np.ndarray:
    res = instrument.run_scan(request, lambda _p: None, threading.Event(), linearization)
    if res.partial:
        raise CalibrationRefused(f"calibration scan stopped early: {res.stop_reason or 'cancelled'}")
    return res.points


def scan_phase_noise(cfg, request: ScanRequest, mzi_delay_s: float) -> str:
    """The phase-noise compensation a scan of ``request`` runs with, "on" or "off" (the scan's own rule,
    :func:`lidard.instrument.dsp_plan.phase_noise_on`, with the monitor delay it is planned with)."""
    mode = request.phase_noise_compensation or cfg.scan.phase_noise_compensation
    return "on" if phase_noise_on(mode, float(request.max_range_m), mzi_delay_s) else "off"


def measure_plate(instrument, optics, known_m: float, linearization: CalibrationResult,
                  applied: AppliedCalibrations) -> PlateMeasurement:
    """Scan the centre region with ``linearization`` (made against ``applied``'s delay) and reduce it.

    The scan already subtracts ``applied.zero_offset_m``: it is added back (the fit wants raw ranges)."""
    req = plate_request(optics, max(2.0, 1.5 * float(known_m)))
    pts = _scan(instrument, req, linearization)
    delay = float(linearization.meta.get("mzi_delay_s") or instrument.monitor_delay_s())
    return plate_measurement(pts, known_m, delay_s=delay, zero_offset_used_m=applied.zero_offset_m,
                             temperature_c=instrument.laser_temperature_c(),
                             linearization_id=linearization.meta.get("id"),
                             phase_noise_compensation=None if getattr(instrument, "cfg", None) is None else
                             scan_phase_noise(instrument.cfg, req, instrument.monitor_delay_s()))


def measure_pointing(instrument, optics, surfaces: list[Surface], linearization: CalibrationResult,
                     noise_m: float) -> tuple[PointingFit, dict[str, Any]]:
    """Scan around the known targets (range-calibrated ranges) and fit the pointing; answers the fit and
    a summary of the scan (pixels, points) for the record."""
    px = scan_pixels(optics, surfaces)
    far = max(float(np.linalg.norm(s.a)) + (s.b if s.kind == "sphere" else 0.0) for s in surfaces)
    req = ScanRequest(pattern="pixels", pixels=tuple((int(r), int(c)) for r, c in px),
                      max_range_m=max(2.0, 1.3 * far), formats=())
    pts = _scan(instrument, req, linearization)
    p = pts[(pts["valid"] == 1) & (pts["return_index"] == 0)]
    fit = fit_pointing(optics, p["row"], p["col"], p["range"].astype(np.float64), surfaces, noise_m=noise_m)
    return fit, {"pixels_scanned": int(len(px)), "valid_points": int(len(p))}


# -- benchmark entry points (no daemon, no store) -----------------------------------------------------
@dataclass
class CalibrationRun:
    """What a benchmark's calibration run gives back."""

    fit: Any                                # RangeFit | PointingFit
    applied: AppliedCalibrations            # now in use by the instrument
    linearization: CalibrationResult        # matches applied's delay: scan with this one
    measurements: list[Any] = dataclasses.field(default_factory=list)


def _linearization_for(instrument, linearization: CalibrationResult | None) -> CalibrationResult:
    want = instrument.monitor_delay_s()
    if linearization is not None and abs(float(linearization.meta.get("mzi_delay_s", want)) - want) <= 1e-9 * want:
        return linearization
    return instrument.linearize()


def run_range_calibration(instrument, known_m: Sequence[float], *, place: Callable[[float], None] | None = None,
                          linearization: CalibrationResult | None = None) -> CalibrationRun:
    """Measure a plate at each known distance, fit, apply (and re-linearize against the new delay).

    ``place(d)`` puts the plate at z = d (default on a simulated bench: ``instrument.set_scene(plate_scene(d))``).
    Raises :class:`CalibrationRefused` when the fit is refused."""
    place = place or (lambda d: instrument.set_scene(plate_scene(d)))
    applied = instrument.applied
    lin = _linearization_for(instrument, linearization)
    ms = []
    for d in known_m:
        place(float(d))
        ms.append(measure_plate(instrument, instrument.optics, float(d), lin, applied))
    fit: RangeFit = fit_range(ms, instrument.cfg.monitor.delay_s)
    # no store here: the id only says "calibrated by a procedure run" in the sidecars
    new = dataclasses.replace(applied, range_id="range-run", delay_s=fit.delay_s, zero_offset_m=fit.zero_offset_m)
    instrument.use_calibrations(new)
    return CalibrationRun(fit, new, _linearization_for(instrument, lin), ms)


def run_pointing_calibration(instrument, geometry: dict[str, Any] | list[Surface], *,
                             place: Callable[[list[Surface]], None] | None = None,
                             linearization: CalibrationResult | None = None,
                             noise_m: float | None = None) -> CalibrationRun:
    """Scan the known targets (``geometry``: the geometry file's dict, or parsed surfaces), fit, apply.

    ``place(surfaces)`` puts them in front of the scanner (default on a simulated bench: spheres and
    planes of the geometry as the scene). ``noise_m``: the single-point range noise the residual is
    judged by; pass the range run's ``fit.pixel_std_m`` (default ``DEFAULT_NOISE_M``, 150 um: the
    simulated bench's plate spread at about 1 m is 75-130 um)."""
    surfaces = geometry if isinstance(geometry, list) else parse_geometry(geometry)
    (place or (lambda s: instrument.set_scene(spheres_scene(s))))(surfaces)
    lin = _linearization_for(instrument, linearization)
    fit, _ = measure_pointing(instrument, instrument.optics, surfaces, lin, DEFAULT_NOISE_M if noise_m is None else noise_m)
    new = dataclasses.replace(instrument.applied, pointing_id="pointing-run", pointing=fit.pointing)
    instrument.use_calibrations(new)
    return CalibrationRun(fit, new, lin)


def run_iq_calibration(instrument, *, linearization: CalibrationResult | None = None,
                       max_range_m: float = 2.0) -> CalibrationRun:
    """Measure the I/Q receiver's imbalance on the scene in front of it (any targets), apply it."""
    require_iq_receiver(instrument)
    lin = _linearization_for(instrument, linearization)
    fit, _ = measure_iq(instrument, instrument.optics, lin, max_range_m=max_range_m)
    new = dataclasses.replace(instrument.applied, iq_id="iq-run", iq_imbalance=(fit.gain, fit.phase_rad))
    instrument.use_calibrations(new)
    return CalibrationRun(fit, new, lin)
