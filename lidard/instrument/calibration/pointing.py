"""Pointing calibration: fit the scanner's pointing model to a known target geometry.

The nominal pointing is eq. 4-1 of the dissertation (§4.1.1: theta = -arctan(x / f)); a real scanner
deviates by a focal-length error, a decentred and rotated array and the lens's radial distortion
(:class:`lidard.physics.optics.Pointing`). Here the deviations are measured: targets of known geometry
(spheres and planes at known poses in the sensor frame; several spheres spread over the field fix all
five parameters) are scanned, every point is placed along its pixel's ray with the range-calibrated
range, and ``scipy.optimize.least_squares`` (soft_l1 loss, robust to the odd stray return) finds the
Pointing that puts the points onto their known surfaces. Points are assigned to the nearest surface
under the starting model within a gate, and again (tighter) under the first fit.

The residual is reported in millimetres (point-to-surface) and in pixels (residual / range x f / pitch,
the angular error in pixel pitches); a fit with too few points, a target that gave no points, or an RMS
residual beyond ``NOISE_FACTOR`` x the range noise is refused.

Geometry file (TOML, sensor frame, metres)::

    [[sphere]]
    centre = [x, y, z]
    radius = 0.05
    [[plane]]            # unbounded plane through point with unit normal
    point = [x, y, z]
    normal = [0, 0, -1]
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...physics.optics import FpsaOptics, Pointing
from ...physics.surfaces import distance_to_plane, distance_to_sphere
from .range import CalibrationRefused

MIN_POINTS = 40          # five parameters, a few surfaces: fewer points cannot tell noise from model
NOISE_FACTOR = 3.0       # refuse an RMS residual above this multiple of the range noise
GATE_M = 0.02            # first assignment: a point farther than this from every surface is not used
MARGIN_PX = 3            # pixels scanned around each sphere's silhouette (the starting model's error)


@dataclass(frozen=True)
class Surface:
    kind: str                     # "sphere" | "plane"
    a: tuple[float, float, float]  # sphere centre / plane point
    b: Any                        # sphere radius / plane unit normal (3-tuple)
    name: str

    def distance(self, pts: np.ndarray) -> np.ndarray:
        if self.kind == "sphere":
            return distance_to_sphere(pts, self.a, self.b, signed=True)
        return distance_to_plane(pts, self.a, self.b, signed=True)

    def as_dict(self) -> dict[str, Any]:
        if self.kind == "sphere":
            return {"kind": "sphere", "name": self.name, "centre": list(self.a), "radius": self.b}
        return {"kind": "plane", "name": self.name, "point": list(self.a), "normal": list(self.b)}


def _vec(where: str, v: Any) -> tuple[float, float, float]:
    try:
        if isinstance(v, (str, bytes)) or any(isinstance(x, bool) for x in v):
            raise TypeError(v)
        out = tuple(float(x) for x in v)
    except (TypeError, ValueError, OverflowError):
        out = ()
    if len(out) != 3 or not all(math.isfinite(x) for x in out):
        raise CalibrationRefused(f"pointing geometry: {where} must be three finite numbers [x, y, z], got {v!r}")
    return out[0], out[1], out[2]


def parse_geometry(d: dict[str, Any], source: str = "<geometry>") -> list[Surface]:
    """Surfaces of a geometry dict (the TOML file's structure); a bad entry is named."""
    if not isinstance(d, dict):
        raise CalibrationRefused(f"pointing geometry {source}: must be a table with [[sphere]] / [[plane]] entries")
    unknown = set(d) - {"sphere", "plane", "name", "description"}
    if unknown:
        raise CalibrationRefused(f"pointing geometry {source}: unknown key(s) {sorted(unknown)}; allowed: sphere, plane")
    for kind in ("sphere", "plane"):
        if not isinstance(d.get(kind, []), list):
            raise CalibrationRefused(f"pointing geometry {source}: {kind} must be a list of tables ([[{kind}]])")
    out: list[Surface] = []
    for i, s in enumerate(d.get("sphere", [])):
        where = f"{source}: sphere[{i}]"
        if not isinstance(s, dict) or set(s) - {"centre", "radius", "name"} or not {"centre", "radius"} <= set(s):
            raise CalibrationRefused(f"pointing geometry {where}: needs exactly centre and radius (and an optional name)")
        r = s["radius"]
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not (math.isfinite(r) and r > 0):
            raise CalibrationRefused(f"pointing geometry {where}.radius: must be > 0 metres, got {r!r}")
        centre = _vec(f"{where}.centre", s["centre"])
        if not centre[2] > r:
            raise CalibrationRefused(f"pointing geometry {where}: must lie wholly in front of the lens "
                                     f"(centre z > radius), got centre {list(centre)}, radius {r}")
        out.append(Surface("sphere", centre, float(r), str(s.get("name", f"sphere[{i}]"))))
    for i, p in enumerate(d.get("plane", [])):
        where = f"{source}: plane[{i}]"
        if not isinstance(p, dict) or set(p) - {"point", "normal", "name"} or not {"point", "normal"} <= set(p):
            raise CalibrationRefused(f"pointing geometry {where}: needs exactly point and normal (and an optional name)")
        n = np.array(_vec(f"{where}.normal", p["normal"]))
        if np.linalg.norm(n) < 1e-9:
            raise CalibrationRefused(f"pointing geometry {where}.normal: must not be zero")
        out.append(Surface("plane", _vec(f"{where}.point", p["point"]), tuple(float(x) for x in n / np.linalg.norm(n)),
                           str(p.get("name", f"plane[{i}]"))))
    if not out:
        raise CalibrationRefused(f"pointing geometry {source}: no [[sphere]] or [[plane]] targets")
    return out


def load_geometry(path: str | Path) -> list[Surface]:
    p = Path(path)
    try:
        return parse_geometry(tomllib.loads(p.read_text()), source=str(p))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CalibrationRefused(f"pointing geometry {p}: cannot read ({exc})") from None


def scan_pixels(optics: FpsaOptics, surfaces: list[Surface]) -> np.ndarray:
    """The bonded pixels to scan: boxes around each sphere's silhouette (plus ``MARGIN_PX``), or every
    bonded pixel when a plane is among the targets (a plane's extent is not known)."""
    bonded = optics.bonded_pixels()
    if any(s.kind == "plane" for s in surfaces):
        return bonded
    dirs = optics.directions(bonded[:, 0], bonded[:, 1])
    keep = np.zeros(len(bonded), dtype=bool)
    step = optics.pitch_m / optics.focal_m
    for s in surfaces:
        c = np.asarray(s.a)
        dist = float(np.linalg.norm(c))
        half = math.asin(min(1.0, s.b / dist)) + MARGIN_PX * step
        near = dirs @ (c / dist) >= math.cos(half)
        if not near.any():
            raise CalibrationRefused(f"pointing calibration: no bonded pixel looks at {s.name} (centre {list(s.a)} m): "
                                     "it is outside the field of view")
        keep |= near
    return bonded[keep]


@dataclass(frozen=True)
class PointingFit:
    pointing: Pointing
    stderr: dict[str, float]
    rms_m: float
    rms_px: float
    median_abs_m: float
    n_points: int
    n_outliers: int
    per_surface: list[dict[str, Any]] = field(default_factory=list)

    def fitted(self) -> dict[str, Any]:
        return {**self.pointing.as_dict(), "stderr": self.stderr}

    def residuals(self) -> dict[str, Any]:
        return {"rms_mm": self.rms_m * 1e3, "rms_px": self.rms_px, "median_abs_mm": self.median_abs_m * 1e3,
                "points": self.n_points, "outliers": self.n_outliers, "per_surface": self.per_surface}


_NAMES = ("focal_scale", "decentre_x_px", "decentre_y_px", "rotation_rad", "k1")
_X_SCALE = np.array([1e-2, 1.0, 1.0, 1e-2, 0.1])
# far beyond any real tolerance (focal +-1 %, 1 pitch, 0.5 deg, |k1| < 0.2), but keeps every trial
# model a valid Pointing (focal_scale > 0) however bad the data
_LOWER = np.array([0.8, -20.0, -20.0, -0.2, -2.0])
_UPPER = np.array([1.25, 20.0, 20.0, 0.2, 2.0])


def _pointing(x: np.ndarray) -> Pointing:
    return Pointing(focal_scale=float(x[0]), decentre_px=(float(x[1]), float(x[2])), rotation_rad=float(x[3]),
                    k1=float(x[4]))


def _points(optics: FpsaOptics, x: np.ndarray, rows, cols, range_m) -> np.ndarray:
    return optics.with_pointing(_pointing(x)).directions(rows, cols) * range_m[:, None]


def _assign(pts: np.ndarray, surfaces: list[Surface], gate_m: float) -> np.ndarray:
    """Index of the nearest surface per point, -1 where none is within ``gate_m``."""
    d = np.abs(np.stack([s.distance(pts) for s in surfaces], axis=1))
    k = np.argmin(d, axis=1)
    return np.where(d[np.arange(len(pts)), k] <= gate_m, k, -1)


def _residual_fn(optics, surfaces, rows, cols, range_m, idx):
    def fn(x: np.ndarray) -> np.ndarray:
        pts = _points(optics, x, rows, cols, range_m)
        out = np.empty(len(pts))
        for j, s in enumerate(surfaces):
            m = idx == j
            out[m] = s.distance(pts[m])
        return out
    return fn


def fit_pointing(optics: FpsaOptics, rows, cols, range_m, surfaces: list[Surface], *, noise_m: float,
                 start: Pointing | None = None, min_points: int = MIN_POINTS) -> PointingFit:
    """Fit :class:`Pointing` so that the points (pixel rays x ``range_m``) lie on ``surfaces``.

    ``noise_m``: the single-point range noise (the range calibration's pixel spread); it sets the
    soft_l1 scale and the refusal limit ``NOISE_FACTOR * noise_m`` on the RMS residual.
    """
    rows, cols = np.asarray(rows), np.asarray(cols)
    range_m = np.asarray(range_m, dtype=np.float64)
    noise_m = float(noise_m)
    if not (math.isfinite(noise_m) and noise_m > 0):
        raise CalibrationRefused(f"pointing calibration: noise_m must be a positive range noise in metres, got {noise_m!r}")
    p0 = start or Pointing()
    x = np.clip(np.array([p0.focal_scale, *p0.decentre_px, p0.rotation_rad, p0.k1], dtype=np.float64),
                _LOWER + 1e-9, _UPPER - 1e-9)
    gate = GATE_M
    first: np.ndarray | None = None
    for _ in range(3):   # assign under the current model, fit, tighten the gate, again
        idx = _assign(_points(optics, x, rows, cols, range_m), surfaces, gate)
        use = idx >= 0
        if first is None:
            first = np.bincount(idx[use], minlength=len(surfaces))
        missing = [s.name for j, s in enumerate(surfaces) if not np.any(idx == j)]
        if use.sum() < min_points or missing:
            raise CalibrationRefused(
                f"pointing calibration: {int(use.sum())} points lie within {gate * 1e3:.1f} mm of the known surfaces "
                f"(need {min_points})" + (f"; no points on {', '.join(missing)}: is the geometry right?" if missing else ""))
        fn = _residual_fn(optics, surfaces, rows[use], cols[use], range_m[use], idx[use])
        from scipy.optimize import least_squares   # on first use: start-up time
        sol = least_squares(fn, x, loss="soft_l1", f_scale=2.0 * noise_m, x_scale=_X_SCALE, method="trf",
                            bounds=(_LOWER, _UPPER))
        x = sol.x
        gate = max(10.0 * noise_m, 1e-4)   # wider than the refusal limit: the RMS test sees the tails
    assert first is not None   # the loop ran
    _check_kept(surfaces, first, np.bincount(idx[use], minlength=len(surfaces)), gate)
    return _summarise(optics, sol, range_m[use], idx[use], surfaces, noise_m, n_out=int((~use).sum()))


def _check_kept(surfaces: list[Surface], first: np.ndarray, last: np.ndarray, gate_m: float) -> None:
    # The robust loss would happily fit the other targets and drop a misplaced one as outliers: a
    # target that loses most of its points is a wrong geometry, not stray returns.
    for j, s in enumerate(surfaces):
        if last[j] < 0.5 * first[j]:
            raise CalibrationRefused(
                f"pointing calibration refused: {s.name}: only {int(last[j])} of its {int(first[j])} points lie within "
                f"{gate_m * 1e3:.2f} mm of its known surface after the fit: its known pose/size is wrong or it moved")


def _summarise(optics, sol, range_m, idx, surfaces, noise_m, n_out) -> PointingFit:
    """The fit ``sol`` (least squares over the points in use, at ``range_m``, on ``surfaces[idx]``) as a
    :class:`PointingFit`, or refused when its residual or its standard errors say the geometry is wrong."""
    x, res = sol.x, sol.fun
    rms = float(np.sqrt(np.mean(res ** 2)))
    px = res / range_m * optics.focal_m / optics.pitch_m
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * np.mean(res ** 2) * len(res) / max(1, len(res) - len(x))
        err = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        err = np.full(len(x), np.inf)
    stderr = dict(zip(_NAMES, (float(e) for e in err)))
    if rms > NOISE_FACTOR * noise_m:
        raise CalibrationRefused(
            f"pointing calibration refused: RMS point-to-surface residual {rms * 1e3:.3f} mm is more than "
            f"{NOISE_FACTOR:g} x the range noise ({noise_m * 1e3:.3f} mm): the geometry is wrong or a target moved")
    if not np.all(np.isfinite(err)) or err[1] > 0.5 or err[2] > 0.5 or err[3] > math.radians(0.2):
        raise CalibrationRefused(
            f"pointing calibration refused: the targets do not fix the model (standard errors {stderr}); "
            "spread spheres over the field of view")
    per = [{"name": s.name, "points": int(np.sum(idx == j)),
            "rms_mm": float(np.sqrt(np.mean(res[idx == j] ** 2)) * 1e3)} for j, s in enumerate(surfaces)]
    return PointingFit(pointing=_pointing(x), stderr=stderr, rms_m=rms, rms_px=float(np.sqrt(np.mean(px ** 2))),
                       median_abs_m=float(np.median(np.abs(res))), n_points=len(res), n_outliers=n_out, per_surface=per)


def spheres_scene(surfaces: list[Surface], reflectivity: float = 0.5) -> dict[str, Any]:
    """A simulated bench's scene with the geometry's spheres and planes placed (the lab places them by hand)."""
    targets = []
    for s in surfaces:
        if s.kind == "sphere":
            targets.append({"kind": "sphere", "center": list(s.a), "radius": s.b, "reflectivity": reflectivity})
        else:
            targets.append({"kind": "plane", "point": list(s.a), "normal": list(s.b), "reflectivity": reflectivity})
    return {"name": "pointing_targets", "target": targets}
