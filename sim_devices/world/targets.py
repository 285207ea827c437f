"""Target types of the simulated world: planes, boxes, spheres and planar polygons (sensor frame).

The scene file loader (:mod:`sim_devices.world.scene`) builds these and the ray caster
(:mod:`sim_devices.world.raycast`) intersects them; both import this module and neither imports
the other's internals, so the two stay free of an import cycle. Units: metres, m/s.
Surface properties common to every kind: ``reflectivity`` (Lambertian albedo; > 1 models the
retro-reflective sheet of the "CAL" letters, §4.4.3), one-way power ``transmission``, ``velocity``
and ``speckle`` (fully developed speckle on the return, see :mod:`sim_devices.world.speckle`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "PlaneTarget",
    "BoxTarget",
    "SphereTarget",
    "PolygonTarget",
    "Target",
    "rotation_matrix_deg",
    "PLANARITY_TOL_M",
    "DEFAULT_REFLECTIVITY",
    "DEFAULT_TRANSMISSION",
]

#: Largest distance (m) of a polygon vertex from the best-fit plane before the polygon is rejected.
PLANARITY_TOL_M = 1e-9

DEFAULT_REFLECTIVITY = 0.1
DEFAULT_TRANSMISSION = 0.0

# --------------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------------


def rotation_matrix_deg(rotation_deg: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    """R = Rz @ Ry @ Rx for right-handed rotations (degrees) about the sensor x, y, z axes.

    Extrinsic order: first about x, then y, then z (all fixed sensor axes). ``R`` maps box-local
    coordinates to sensor-frame directions.
    """
    rx, ry, rz = (math.radians(float(a)) for a in rotation_deg)
    cx, sx = math.cos(rx), math.sin(rx)
    cy, sy = math.cos(ry), math.sin(ry)
    cz, sz = math.cos(rz), math.sin(rz)
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    r_y = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    r_z = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return r_z @ r_y @ r_x


def _plane_axes(normal: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """In-plane unit axes (u, v): v = up projected into the plane, u = v x n (across up)."""
    v = up - np.dot(up, normal) * normal
    v = v / np.linalg.norm(v)
    u = np.cross(v, normal)
    return u / np.linalg.norm(u), v


def _is_parallel(a: np.ndarray, b: np.ndarray) -> bool:
    """True when unit vector ``a`` and vector ``b`` are (numerically) parallel."""
    bn = b / np.linalg.norm(b)
    return bool(np.linalg.norm(np.cross(a, bn)) < 1e-9)


# --------------------------------------------------------------------------------------------------
# Targets
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _TargetBase:
    reflectivity: float
    transmission: float
    velocity: np.ndarray  # (3,) m/s
    speckle: bool = False  # fully developed speckle on its returns (sim_devices.world.speckle)

    def __post_init__(self) -> None:
        # Targets are shared between scenes (moved(), to_dict()); freeze their arrays too.
        for value in vars(self).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    def _common_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "reflectivity": float(self.reflectivity),
            "transmission": float(self.transmission),
            "velocity": [float(c) for c in self.velocity],
        }
        if self.speckle:  # written only when on, so the shipped scenes' dicts are unchanged
            d["speckle"] = True
        return d


@dataclass(frozen=True, eq=False)
class PlaneTarget(_TargetBase):
    """Infinite plane, or a w x h rectangle centred on ``point`` when ``size`` is given."""

    kind: ClassVar[str] = "plane"
    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))  # unit
    size: np.ndarray | None = None  # (w, h) or None for infinite
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))  # as given/resolved

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(u, v): width axis (perpendicular to up) and height axis (along up) in the plane."""
        return _plane_axes(self.normal, self.up)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "kind": "plane",
            "point": [float(c) for c in self.point],
            "normal": [float(c) for c in self.normal],
        }
        if self.size is not None:
            d["size"] = [float(c) for c in self.size]
            d["up"] = [float(c) for c in self.up]
        d.update(self._common_dict())
        return d


@dataclass(frozen=True, eq=False)
class BoxTarget(_TargetBase):
    """Oriented box: ``center``, full edge lengths ``size``, rotation R (box-local -> sensor)."""

    kind: ClassVar[str] = "box"
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    size: np.ndarray = field(default_factory=lambda: np.ones(3))
    rotation_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def rotation(self) -> np.ndarray:
        return rotation_matrix_deg(self.rotation_deg)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "kind": "box",
            "center": [float(c) for c in self.center],
            "size": [float(c) for c in self.size],
            "rotation_deg": [float(c) for c in self.rotation_deg],
        }
        d.update(self._common_dict())
        return d


@dataclass(frozen=True, eq=False)
class SphereTarget(_TargetBase):
    kind: ClassVar[str] = "sphere"
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "kind": "sphere",
            "center": [float(c) for c in self.center],
            "radius": float(self.radius),
        }
        d.update(self._common_dict())
        return d


@dataclass(frozen=True, eq=False)
class PolygonTarget(_TargetBase):
    """Planar, possibly non-convex polygon (letters, signs); inside by the even-odd rule."""

    kind: ClassVar[str] = "polygon"
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # (m, 3)
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))  # unit, Newell
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))  # vertex centroid, on the plane
    u: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))  # 2D frame axes
    v: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    vertices_2d: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))  # (m, 2) in (u, v)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "kind": "polygon",
            "vertices": [[float(c) for c in p] for p in self.vertices],
        }
        d.update(self._common_dict())
        return d


Target = PlaneTarget | BoxTarget | SphereTarget | PolygonTarget
