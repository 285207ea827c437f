"""Range scale and zero calibration from a flat plate at known distances.

Physics (dissertation §2.1.1, eq. 2-3: R = c f_b / (2 kappa); §2.2: the ILC locks the chirp to the
monitor MZI). The ILC makes the MZI beat equal ``kappa_nom * tau_used`` measured through the TRUE MZI
delay ``tau_true``, so the true chirp rate is ``kappa_nom * tau_used / tau_true``. A range computed with
``kappa_nom`` is therefore

    R_raw = (tau_used / tau_true) (R + z0)

with ``z0`` the optical path between the reference reflection and the lens (fibre, lens) that every
return carries. Dividing by ``tau_used`` makes the model linear in two unknowns::

    q = R_raw / tau_used = a R + b,      a = 1 / tau_true,   b = z0 / tau_true

so measurements taken under different linearizations (different ``tau_used``) fit together. The fit is
weighted least squares with each plate's standard error (pixel spread / sqrt(n)); its chi-square is
tested against the noise (p < ``P_MIN``: refused, naming the plate with the largest normalised residual,
typically a plate entered at the wrong known distance). The result is the effective MZI delay
``tau_eff = tau_true`` (the ILC target and the phase-noise compensation use it, so the chirp itself
becomes right) and ``z0`` (subtracted from every range).

The plate: a flat plane perpendicular to the optical axis at z = ``known_m`` (the lab's reference plate
on a rail, its distance read from the rail's scale to the sensor frame's origin, the lens centre). The
range along a pixel's ray of unit direction d is ``known_m / d_z``; only a small centre region of
pixels is used (|d_z - 1| < 1e-4 there, so the pointing model does not matter).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any
from collections.abc import Sequence

import numpy as np

from ..errors import InstrumentError
from ..types import ScanRequest

P_MIN = 1e-3            # a fit whose chi-square is less likely than this under the noise is refused
MIN_PIXELS = 8          # valid plate returns a measurement needs
SEM_FLOOR_M = 1e-6      # float32 ranges (0.06 um at 1 m) and the DSP's interpolation: no plate is better
DEFAULT_NOISE_M = 150e-6  # single-point range noise for the pointing check when no plate spread is known
ROI_HALF = 3            # centre region: up to 2*ROI_HALF bonded rows x 2*ROI_HALF columns


class CalibrationRefused(InstrumentError):
    """A calibration's measurements do not support a fit (too few, inconsistent); the message says why."""

    http_status = 422


@dataclass(frozen=True)
class PlateMeasurement:
    """One plate at a known distance, reduced to what the fit needs (and what the record keeps)."""

    known_m: float               # the plate plane z = known_m in the sensor frame
    known_range_m: float         # mean over the pixels of known_m / d_z (the true ray ranges)
    raw_range_m: float           # mean measured range with the zero offset NOT removed
    sem_m: float                 # standard error of raw_range_m (pixel spread / sqrt(n), floored)
    pixel_std_m: float           # spread of the single pixels about the plate (the range noise)
    n: int                       # valid pixels
    delay_s: float               # the monitor delay the chirp was linearized against (tau_used)
    temperature_c: float = float("nan")
    linearization_id: str | None = None
    #: the plate scan's resolved phase-noise compensation, "on" or "off" (None: not recorded); a range
    #: record holds plates of one mode and applies to scans in that mode (setup.mode_differs)
    phase_noise_compensation: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PlateMeasurement:
        names = cls.__dataclass_fields__
        return cls(**{k: v for k, v in d.items() if k in names})


@dataclass(frozen=True)
class RangeFit:
    """The fitted effective monitor delay and zero offset, with the fit's statistics."""

    delay_s: float               # tau_eff: use wherever the nominal monitor.delay_s was used
    zero_offset_m: float         # z0: subtract from every range
    nominal_delay_s: float
    delay_stderr_s: float
    zero_offset_stderr_m: float
    chi2: float
    dof: int
    p_value: float               # NaN with dof = 0 (two plates: the fit is exact, nothing is checked)
    residuals_m: tuple[float, ...]
    normalized_residuals: tuple[float, ...]
    pixel_std_m: float           # pooled single-pixel range noise of the plates
    #: covariance of (delay_s, zero_offset_m), s m: with both standard errors, the range error the fit
    #: leaves at any range (AppliedCalibrations.range_uncertainty_m)
    delay_zero_offset_cov: float = 0.0

    @property
    def scale(self) -> float:
        """s = tau_nom / tau_eff: the raw range's scale error with the nominal delay."""
        return self.nominal_delay_s / self.delay_s

    def fitted(self) -> dict[str, Any]:
        return {"delay_s": self.delay_s, "zero_offset_m": self.zero_offset_m, "scale": self.scale,
                "nominal_delay_s": self.nominal_delay_s, "delay_stderr_s": self.delay_stderr_s,
                "zero_offset_stderr_m": self.zero_offset_stderr_m, "delay_zero_offset_cov": self.delay_zero_offset_cov}

    def residuals(self) -> dict[str, Any]:
        return {"chi2": self.chi2, "dof": self.dof, "p_value": self.p_value,
                "residuals_m": list(self.residuals_m), "normalized": list(self.normalized_residuals),
                "pixel_std_m": self.pixel_std_m, "checked": self.dof > 0}


def _chi2_sf(x, dof):
    # imported on first use: scipy.stats costs ~0.3 s of every command's start-up
    from scipy import stats
    return stats.chi2.sf(x, dof)


def plate_request(optics, max_range_m: float) -> ScanRequest:
    """The centre-region ROI a plate measurement scans (bonded rows only are scanned)."""
    return centre_request(optics, max_range_m, ROI_HALF)


def centre_request(optics, max_range_m: float, half: int, **kw) -> ScanRequest:
    """An ROI of up to 2 ``half`` bonded rows x 2 ``half`` columns around the array's centre, no
    outputs written (the calibration scans); ``kw``: other ScanRequest fields (averages)."""
    rows = list(optics.bonded_rows)
    mid = len(rows) // 2
    r_lo, r_hi = rows[max(0, mid - half)], rows[min(len(rows) - 1, mid + half - 1)] + 1
    c_mid = optics.cols // 2
    return ScanRequest(pattern="roi", rows=(r_lo, r_hi), cols=(max(0, c_mid - half), min(optics.cols, c_mid + half)),
                       max_range_m=float(max_range_m), formats=(), **kw)


def plate_measurement(points: np.ndarray, known_m: float, *, delay_s: float, zero_offset_used_m: float = 0.0,
                      temperature_c: float = float("nan"), linearization_id: str | None = None,
                      phase_noise_compensation: str | None = None) -> PlateMeasurement:
    """Reduce a plate scan's points (POINT_DTYPE) to a :class:`PlateMeasurement`.

    ``zero_offset_used_m``: the zero offset the scan already subtracted (added back: the fit wants raw
    ranges). Only valid first returns count; fewer than ``MIN_PIXELS`` is refused (plate missing, too
    near for an unambiguous beat, or too dark).
    """
    known_m = float(known_m)
    if not (math.isfinite(known_m) and known_m > 0):
        raise CalibrationRefused(f"range calibration: known_m must be a positive distance in metres, got {known_m!r}")
    p = points[(points["valid"] == 1) & (points["return_index"] == 0)]
    if len(p) < MIN_PIXELS:
        raise CalibrationRefused(
            f"range calibration: plate at known_m={known_m:g}: only {len(p)} of the centre pixels gave a valid "
            f"return (need {MIN_PIXELS}); is the plate there, bright enough and beyond the nearest unambiguous range?")
    dz = p["z"].astype(np.float64) / p["range"]     # the unit ray's z component, as the scan placed it
    raw = p["range"].astype(np.float64) + float(zero_offset_used_m)
    # the spread about the plane (z = range * d_z), so the few-um geometric spread of known_m / d_z over
    # the region does not count as noise
    std = float(np.std(raw * dz, ddof=1))
    return PlateMeasurement(known_m=known_m, known_range_m=float(np.mean(known_m / dz)), raw_range_m=float(raw.mean()),
                            sem_m=max(std / math.sqrt(len(p)), SEM_FLOOR_M), pixel_std_m=std, n=int(len(p)),
                            delay_s=float(delay_s), temperature_c=float(temperature_c),
                            linearization_id=linearization_id, phase_noise_compensation=phase_noise_compensation)


def _describe(i: int, m: PlateMeasurement, resid_m: float, norm: float) -> str:
    return (f"measurement #{i + 1} (known_m={m.known_m:g}) is off by {resid_m * 1e3:+.3f} mm "
            f"({norm:+.1f} standard errors)")


def _wls(R: np.ndarray, q: np.ndarray, sig: np.ndarray):
    """Weighted straight line q = a R + b: (a, b, covariance, normalised residuals, chi-square)."""
    A = np.stack([R, np.ones_like(R)], axis=1) / sig[:, None]
    coef, *_ = np.linalg.lstsq(A, q / sig, rcond=None)
    a, b = float(coef[0]), float(coef[1])
    norm = (q - (a * R + b)) / sig
    return a, b, np.linalg.inv(A.T @ A), norm, float(np.sum(norm ** 2))


def _culprit(ms, R, q, sig, resid_m, norm, p_min: float) -> str:
    """Which plate to check. With four or more, the one whose removal leaves a consistent fit (leave
    one out); with three, a straight line through any two predicts the third equally badly, so the
    largest normalised residual is named with that caveat."""
    n = len(ms)
    if n >= 4:
        keep = np.ones(n, dtype=bool)
        chi_without = []
        for i in range(n):
            keep[:] = True
            keep[i] = False
            chi_without.append(_wls(R[keep], q[keep], sig[keep])[4])
        k = int(np.argmin(chi_without))
        if _chi2_sf(chi_without[k], n - 3) >= p_min:
            return (f"{_describe(k, ms[k], resid_m[k], norm[k])}; without it the others agree "
                    f"(chi-square {chi_without[k]:.1f} for {n - 3}): check its known distance, remove it and measure again")
    k = int(np.argmax(np.abs(norm)))
    return (f"largest: {_describe(k, ms[k], resid_m[k], norm[k])}"
            + ("; three plates cannot tell which one is wrong: check every known distance or add a fourth plate"
               if n == 3 else "; check the known distances, remove the wrong one and measure again"))


def fit_range(measurements: Sequence[PlateMeasurement], nominal_delay_s: float, *, p_min: float = P_MIN) -> RangeFit:
    """Weighted least squares of q = R_raw / tau_used = a R + b over the plates (module docstring).

    Refuses (:class:`CalibrationRefused`) fewer than two distinct distances, and a fit whose chi-square
    has p < ``p_min``, naming the plate with the largest normalised residual.
    """
    ms = list(measurements)
    known = sorted({round(m.known_m, 6) for m in ms})
    if len(known) < 2:
        raise CalibrationRefused(f"range calibration: need plates at >= 2 different known distances, have "
                                 f"{len(ms)} measurement(s) at {known or 'none'} m")
    R = np.array([m.known_range_m for m in ms])
    tau = np.array([m.delay_s for m in ms])
    q = np.array([m.raw_range_m for m in ms]) / tau
    sig = np.array([m.sem_m for m in ms]) / tau
    a, b, cov, norm, chi2 = _wls(R, q, sig)
    if not a > 0:
        raise CalibrationRefused(f"range calibration: the fitted range scale is not positive (a={a:g}); "
                                 "are the known distances entered in metres?")
    resid_m = norm * sig * tau               # back in range metres
    dof = len(ms) - 2
    p = float(_chi2_sf(chi2, dof)) if dof > 0 else float("nan")
    if dof > 0 and p < p_min:
        raise CalibrationRefused(
            f"range calibration refused: chi-square {chi2:.1f} for {dof} degree(s) of freedom (p = {p:.2g} < "
            f"{p_min:g}): the plates disagree more than their noise explains; "
            + _culprit(ms, R, q, sig, resid_m, norm, p_min))
    tau_eff, z0 = 1.0 / a, b / a
    # propagate (a, b) -> (tau = 1/a, z0 = b/a)
    j = np.array([[-1.0 / a**2, 0.0], [-b / a**2, 1.0 / a]])
    c2 = j @ cov @ j.T
    pooled = float(np.sqrt(np.sum([(m.n - 1) * m.pixel_std_m**2 for m in ms]) / max(1, sum(m.n - 1 for m in ms))))
    return RangeFit(delay_s=tau_eff, zero_offset_m=z0, nominal_delay_s=float(nominal_delay_s),
                    delay_stderr_s=float(np.sqrt(c2[0, 0])), zero_offset_stderr_m=float(np.sqrt(c2[1, 1])),
                    chi2=chi2, dof=dof, p_value=p, residuals_m=tuple(float(x) for x in resid_m),
                    normalized_residuals=tuple(float(x) for x in norm), pixel_std_m=pooled,
                    delay_zero_offset_cov=float(c2[0, 1]))


def plate_scene(distance_m: float, size_m: float = 0.6, reflectivity: float = 0.5) -> dict[str, Any]:
    """A simulated bench's scene with the reference plate at z = ``distance_m`` (what a lab does by hand
    on the rail; the daemon's procedure itself only takes ``known_m``)."""
    return {"name": f"plate_{distance_m:g}m",
            "target": [{"kind": "plane", "point": [0.0, 0.0, float(distance_m)], "normal": [0.0, 0.0, -1.0],
                        "size": [size_m, size_m], "reflectivity": reflectivity}]}
