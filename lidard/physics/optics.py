"""FPSA beam-scanner optics: pixel (row, col) <-> antenna position <-> beam direction.

Follows dissertation §4.1.1-§4.1.2 and Table 4-1:

* beam angle per axis ``theta = -arctan(x / f)`` (eq. 4-1): the antenna at focal-plane offset ``x``
  emits a collimated beam on the opposite side of the optical axis;
* field of view ``FoV = 2 arctan(L / 2f)`` with array size ``L = (N - 1) * pitch`` (eqs. 4-2, 4-5);
* resolution ``l / f`` at the array centre (eq. 4-4), ``f l / (f^2 + x^2)`` elsewhere (eq. 4-3);
* divergence ``W / f`` (eqs. 4-7, 4-9) and, for a Gaussian emitter, FWHM ``sqrt(2 ln 2) W / f``
  (~1.18 W/f, eq. 4-16).

Frames: the sensor frame has its origin at the lens centre, +z along the optical axis toward the
scene, +x right, +y up. Column index grows with +x on the chip, row index grows with -y on the chip
(row 0 at the top of the die as seen from the lens). Because of the minus sign in eq. 4-1 the beam of
column 0 therefore points to +x (right) and the beam of row 0 to -y (down), i.e. the image is inverted,
exactly as a camera's.

Pure numpy; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike
from typing import Any

GAUSSIAN_FWHM_FACTOR = float(np.sqrt(2.0 * np.log(2.0)))  # eq. 4-16, ~1.177


@dataclass(frozen=True)
class Pointing:
    """Deviations of a real scanner from the nominal pointing of eq. 4-1.

    An antenna at nominal chip position (x, y) (:meth:`FpsaOptics.antenna_xy_m`) sits, on the real
    die, rotated by ``rotation_rad`` about the optical axis and shifted by ``decentre_px`` (x, y) pixel
    pitches; the lens's true focal length is ``focal_m * focal_scale``; its radial distortion maps the
    ideal image coordinate u = x / f to u (1 + k1 |u|^2) (the single-term Brown model that a
    low-distortion F/1.4 25 mm lens needs: |k1| <~ 0.2, i.e. <~ 0.4 % at the FPSA's edge field).
    The beam direction is (-u, -v, 1) normalised. All zero / one: eq. 4-1 exactly.
    """

    focal_scale: float = 1.0
    decentre_px: tuple[float, float] = (0.0, 0.0)
    rotation_rad: float = 0.0
    k1: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.focal_scale, *self.decentre_px, self.rotation_rad, self.k1)
        if not all(np.isfinite(v) for v in vals) or self.focal_scale <= 0:
            raise ValueError(f"Pointing: every value must be finite and focal_scale > 0, got {self!r}")

    @property
    def nominal(self) -> bool:
        return (self.focal_scale == 1.0 and tuple(self.decentre_px) == (0.0, 0.0)
                and self.rotation_rad == 0.0 and self.k1 == 0.0)

    def image_coords(self, x_m: ArrayLike, y_m: ArrayLike, focal_m: float, pitch_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Normalised image coordinates (u, v) of antennas at nominal chip positions (x, y)."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        if self.nominal:
            return x / focal_m, y / focal_m
        c, s = np.cos(self.rotation_rad), np.sin(self.rotation_rad)
        xr = c * x - s * y + self.decentre_px[0] * pitch_m
        yr = s * x + c * y + self.decentre_px[1] * pitch_m
        f = focal_m * self.focal_scale
        u, v = xr / f, yr / f
        g = 1.0 + self.k1 * (u * u + v * v)
        return u * g, v * g

    def chip_coords(self, u: ArrayLike, v: ArrayLike, focal_m: float, pitch_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`image_coords`: nominal chip positions (x, y) of image coordinates (u, v)."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if self.nominal:
            return u * focal_m, v * focal_m
        r_d = np.hypot(u, v)
        r = r_d.copy()
        for _ in range(8):  # Newton on r (1 + k1 r^2) = r_d; |k1 r^2| << 1 converges in a few steps
            r = r - (r * (1.0 + self.k1 * r * r) - r_d) / (1.0 + 3.0 * self.k1 * r * r)
        scale = np.divide(r, r_d, out=np.ones_like(r_d), where=r_d > 0)
        f = focal_m * self.focal_scale
        xr = u * scale * f - self.decentre_px[0] * pitch_m
        yr = v * scale * f - self.decentre_px[1] * pitch_m
        c, s = np.cos(self.rotation_rad), np.sin(self.rotation_rad)
        return c * xr + s * yr, -s * xr + c * yr

    def as_dict(self) -> dict[str, Any]:
        return {"focal_scale": self.focal_scale, "decentre_px": list(self.decentre_px),
                "rotation_rad": self.rotation_rad, "k1": self.k1}


@dataclass(frozen=True)
class FpsaOptics:
    """Geometry of an N_rows x N_cols FPSA behind a device lens of focal length ``focal_m``."""

    rows: int
    cols: int
    pitch_m: float
    emission_w_m: float
    focal_m: float
    bonded_rows: tuple[int, ...] = field(default=())
    wavelength_m: float = 1.55e-6
    #: the pointing model's deviations from the nominal design; all zero: eq. 4-1 exactly.
    #: The simulated bench draws hidden true values (``[sim.tolerances]``); the daemon uses the values
    #: its pointing calibration fitted. See :class:`Pointing`.
    pointing: Pointing = field(default_factory=lambda: Pointing())

    def __post_init__(self) -> None:
        if self.rows < 1 or self.cols < 1:
            raise ValueError(f"FpsaOptics: rows and cols must be >= 1, got {self.rows}x{self.cols}")
        for name in ("pitch_m", "emission_w_m", "focal_m", "wavelength_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"FpsaOptics: {name} must be a positive finite number, got {value!r}")
        if not self.bonded_rows:
            object.__setattr__(self, "bonded_rows", tuple(range(self.rows)))
        bad = [r for r in self.bonded_rows if not 0 <= r < self.rows]
        if bad:
            raise ValueError(f"FpsaOptics: bonded row {bad[0]} outside 0..{self.rows - 1}")

    # -- array geometry -------------------------------------------------------------------------
    @property
    def size_m(self) -> tuple[float, float]:
        """Array extent (L_x, L_y) between the outermost antenna centres, eq. 4-5."""
        return ((self.cols - 1) * self.pitch_m, (self.rows - 1) * self.pitch_m)

    def antenna_xy_m(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Antenna centre on the focal plane, relative to the optical axis (array centre)."""
        row = np.asarray(row, dtype=np.float64)
        col = np.asarray(col, dtype=np.float64)
        x = (col - (self.cols - 1) / 2.0) * self.pitch_m
        y = ((self.rows - 1) / 2.0 - row) * self.pitch_m
        return x, y

    def pixel_from_xy(self, x_m: ArrayLike, y_m: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Nearest (row, col) to a focal-plane position; clipped to the array."""
        col = np.rint(np.asarray(x_m) / self.pitch_m + (self.cols - 1) / 2.0)
        row = np.rint((self.rows - 1) / 2.0 - np.asarray(y_m) / self.pitch_m)
        return (np.clip(row, 0, self.rows - 1).astype(np.int64),
                np.clip(col, 0, self.cols - 1).astype(np.int64))

    # -- beam directions ------------------------------------------------------------------------
    def beam_angles_rad(self, row: ArrayLike, col: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis steering angles (theta_x, theta_y) of eq. 4-1."""
        x, y = self.antenna_xy_m(row, col)
        return -np.arctan(x / self.focal_m), -np.arctan(y / self.focal_m)

    def directions(self, row: ArrayLike, col: ArrayLike) -> np.ndarray:
        """Unit beam direction vectors, shape (..., 3), in the sensor frame (with :attr:`pointing`)."""
        x, y = self.antenna_xy_m(row, col)
        u, v = self.pointing.image_coords(x, y, self.focal_m, self.pitch_m)
        d = np.stack([-u, -v, np.ones_like(u)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pixel_from_direction(self, direction: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`directions`: the pixel whose beam is nearest to ``direction``."""
        d = np.asarray(direction, dtype=np.float64)
        if np.any(d[..., 2] <= 0):
            raise ValueError("pixel_from_direction: direction must point into the scene (z > 0)")
        x, y = self.pointing.chip_coords(-d[..., 0] / d[..., 2], -d[..., 1] / d[..., 2], self.focal_m, self.pitch_m)
        return self.pixel_from_xy(x, y)

    def with_pointing(self, pointing: Pointing) -> FpsaOptics:
        """The same scanner with another pointing model (a calibration's fit, or the bench's truth)."""
        return replace(self, pointing=pointing)

    # -- figures of merit (Table 4-1) -----------------------------------------------------------
    @property
    def fov_deg(self) -> tuple[float, float]:
        lx, ly = self.size_m
        return (float(np.degrees(2 * np.arctan(lx / (2 * self.focal_m)))),
                float(np.degrees(2 * np.arctan(ly / (2 * self.focal_m)))))

    @property
    def resolution_deg(self) -> tuple[float, float]:
        """Angular step between adjacent beams at the array centre, eq. 4-4 (same on both axes)."""
        r = float(np.degrees(self.pitch_m / self.focal_m))
        return (r, r)

    def resolution_at_deg(self, x_m: ArrayLike) -> np.ndarray:
        """Local angular step at focal-plane offset x, eq. 4-3 (finer toward the edge)."""
        x = np.asarray(x_m, dtype=np.float64)
        return np.degrees(self.focal_m * self.pitch_m / (self.focal_m**2 + x**2))

    @property
    def divergence_deg(self) -> tuple[float, float]:
        """Geometric / diffraction divergence W/f, eqs. 4-7 and 4-9."""
        d = float(np.degrees(self.emission_w_m / self.focal_m))
        return (d, d)

    @property
    def gaussian_fwhm_deg(self) -> tuple[float, float]:
        """FWHM divergence of a Gaussian emitter, sqrt(2 ln 2) W/f, eq. 4-16."""
        d = GAUSSIAN_FWHM_FACTOR * float(np.degrees(self.emission_w_m / self.focal_m))
        return (d, d)

    @property
    def beam_waist_m(self) -> float:
        """Waist radius of the output Gaussian beam, lambda f / (pi W), at the front focal plane."""
        return self.wavelength_m * self.focal_m / (np.pi * self.emission_w_m)

    def bonded_pixels(self) -> np.ndarray:
        """All addressable (row, col) pairs, row-major, shape (n, 2)."""
        rows = np.asarray(self.bonded_rows, dtype=np.int64)
        rr, cc = np.meshgrid(rows, np.arange(self.cols), indexing="ij")
        return np.stack([rr.ravel(), cc.ravel()], axis=1)

    def summary(self) -> dict[str, Any]:
        """The figures `lidarctl optics --json` and GET /scanner report."""
        return {
            "fov_deg": list(self.fov_deg),
            "resolution_deg": list(self.resolution_deg),
            "divergence_deg": list(self.divergence_deg),
            "gaussian_fwhm_deg": list(self.gaussian_fwhm_deg),
            "pixels": [self.rows, self.cols],
            "bonded_rows": len(self.bonded_rows),
            "focal_m": self.focal_m,
            "pitch_m": self.pitch_m,
            "emission_w_m": self.emission_w_m,
        }


def bonded_rows_skip(rows: int, skip_every: int, skip_offset: int) -> tuple[int, ...]:
    """Rows wired to the driver when one row in every ``skip_every`` is left unbonded (§4.3.3)."""
    if skip_every <= 0:
        return tuple(range(rows))
    return tuple(r for r in range(rows) if r % skip_every != skip_offset % skip_every)
