"""Scene model of the simulated world: targets in the sensor frame, TOML/dict loading, ray casts.

The simulated FPSA LiDAR looks at a static set of targets (planes, boxes, spheres, planar polygons),
each with a Lambertian albedo (``reflectivity``; > 1 models the retro-reflective traffic-sign sheet
of the dissertation's "CAL" letters, §4.4.3), a one-way power ``transmission`` (a glass pane gives a
return *and* lets light through to what is behind it) and a ``velocity`` (FMCW Doppler term).

Sensor frame (used everywhere in this module): origin at the device-lens centre, +z along the
optical axis toward the scene, +x right, +y up, metres and m/s. A beam for antenna offset (x, y) in
the focal plane of a lens of focal length f points along (-x/f, -y/f, 1) normalised (eq. 4-1); that
mapping belongs to the optics/bench, not here: :meth:`Scene.cast` takes arbitrary unit directions.

Scene file format (TOML; see config/scenes/*.toml)::

    name = "..."            # optional
    description = "..."     # optional
    mixed_pixels = true     # optional, default true: the bench samples the beam footprint with
                            # sub-rays where it crosses a target's outline (a depth step or a
                            # target edge: two weaker returns or one blended; sim_devices.world.
                            # footprint), one ray elsewhere; false: one ray per pixel everywhere
    [[target]]
    kind = "plane" | "box" | "sphere" | "polygon"
    reflectivity = 0.1      # >= 0, default 0.1
    transmission = 0.0      # in [0, 1], default 0
    velocity = [vx, vy, vz] # m/s, default 0. Positions are those at scene time t = 0, the scan's first
                            # measured pixel (the run's first trigger; t = 0 of every point's ``t``).
                            # Each beam sees the target at its own trigger time t, moved by velocity * t
                            # (sim_devices.world.motion); the radial part also gives the Doppler shift
    speckle = false         # true: rough surface, fully developed speckle on its returns (Rayleigh
                            # amplitude, uniform phase; new per pixel, and per chirp if it moves;
                            # sim_devices.world.speckle). Default false (a smooth, non-fading return)
    # plane:   point, normal, optional size = [w, h] (rectangle centred on point) and up = [x, y, z]
    #          (h along up projected into the plane, w along the in-plane axis perpendicular to up;
    #          default up = +y, or +z when the normal is parallel to y)
    # box:     center, size = [sx, sy, sz], optional rotation_deg = [rx, ry, rz]
    #          (extrinsic about sensor x, then y, then z: R = Rz @ Ry @ Rx; box-local -> sensor)
    # sphere:  center, radius
    # polygon: vertices = [[x, y, z], ...]  (>= 3, planar within 1e-9 m; may be non-convex)

Loading is all-or-nothing: the first problem raises one :class:`SceneError` whose message names the
source, the target index and the key, e.g. ``scene.toml: target[3].radius: must be > 0, got -1``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sim_devices.world import surface_truth
from sim_devices.world.raycast import Hits, cast
from sim_devices.world.targets import (
    DEFAULT_REFLECTIVITY,
    DEFAULT_TRANSMISSION,
    PLANARITY_TOL_M,
    BoxTarget,
    PlaneTarget,
    PolygonTarget,
    SphereTarget,
    Target,
    _is_parallel,
    _plane_axes,
    rotation_matrix_deg,
)

__all__ = [
    "SceneError",
    "PlaneTarget",
    "BoxTarget",
    "SphereTarget",
    "PolygonTarget",
    "Target",
    "Scene",
    "rotation_matrix_deg",
    "PLANARITY_TOL_M",
]

Kind = Literal["plane", "box", "sphere", "polygon"]


class SceneError(ValueError):
    """A scene description is invalid; the message names source, target index and key."""


# --------------------------------------------------------------------------------------------------
# Validation (one error, naming source / target / key)
# --------------------------------------------------------------------------------------------------

_COMMON_KEYS = ("kind", "reflectivity", "transmission", "velocity", "speckle")
_KIND_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # kind: (required keys, optional keys) besides the common ones
    "plane": (("point", "normal"), ("size", "up")),
    "box": (("center", "size"), ("rotation_deg",)),
    "sphere": (("center", "radius"), ()),
    "polygon": (("vertices",), ()),
}
_TOP_KEYS = ("name", "description", "mixed_pixels", "target")


class _Ctx:
    """Builds error messages ``<source>: target[i].<key>: <problem>``."""

    def __init__(self, source: str, index: int | None = None) -> None:
        self.source = source
        self.index = index

    def error(self, key: str | None, problem: str) -> SceneError:
        where = self.source
        if self.index is not None:
            where += f": target[{self.index}]"
            if key:
                where += f".{key}"
        elif key:
            where += f": {key}"
        return SceneError(f"{where}: {problem}")


def _is_number(x: Any) -> bool:
    # bool is an int subclass; `true` is not a coordinate.
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _number(ctx: _Ctx, key: str, x: Any) -> float:
    if not _is_number(x):
        raise ctx.error(key, f"must be a number, got {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise ctx.error(key, f"must be finite, got {x!r}")
    return v


def _vector(ctx: _Ctx, key: str, x: Any, n: int) -> np.ndarray:
    if not isinstance(x, (list, tuple)) or len(x) != n:
        got = f"{len(x)} values" if isinstance(x, (list, tuple)) else repr(x)
        raise ctx.error(key, f"must be a list of {n} numbers, got {got}")
    out = np.empty(n, dtype=np.float64)
    for i, c in enumerate(x):
        if not _is_number(c):
            raise ctx.error(key, f"must be a list of {n} numbers, element {i} is {c!r}")
        if not math.isfinite(float(c)):
            raise ctx.error(key, f"must contain finite numbers, element {i} is {c!r}")
        out[i] = float(c)
    return out


def _positive_vector(ctx: _Ctx, key: str, x: Any, n: int) -> np.ndarray:
    v = _vector(ctx, key, x, n)
    if np.any(v <= 0.0):
        raise ctx.error(key, f"all elements must be > 0, got {[float(c) for c in v]}")
    return v


def _unit(ctx: _Ctx, key: str, x: Any) -> np.ndarray:
    v = _vector(ctx, key, x, 3)
    norm = float(np.linalg.norm(v))
    if not norm > 0.0:
        raise ctx.error(key, f"must be a non-zero vector, got {[float(c) for c in v]}")
    return v / norm


def _polygon(ctx: _Ctx, x: Any, common: dict[str, Any]) -> PolygonTarget:
    key = "vertices"
    if not isinstance(x, (list, tuple)) or len(x) < 3:
        got = f"{len(x)} vertices" if isinstance(x, (list, tuple)) else repr(x)
        raise ctx.error(key, f"must be a list of >= 3 [x, y, z] vertices, got {got}")
    verts = np.array([_vector(ctx, f"{key}[{i}]", p, 3) for i, p in enumerate(x)])
    # Newell's method: robust normal of a (possibly non-convex) planar polygon; its length is
    # twice the area, so a zero length means a degenerate (collinear / zero-area) polygon.
    nxt = np.roll(verts, -1, axis=0)
    newell = np.array(
        [
            np.sum((verts[:, 1] - nxt[:, 1]) * (verts[:, 2] + nxt[:, 2])),
            np.sum((verts[:, 2] - nxt[:, 2]) * (verts[:, 0] + nxt[:, 0])),
            np.sum((verts[:, 0] - nxt[:, 0]) * (verts[:, 1] + nxt[:, 1])),
        ]
    )
    extent = float(np.max(np.ptp(verts, axis=0)))
    area2 = float(np.linalg.norm(newell))
    if not area2 > 1e-12 * max(extent, 1e-300) ** 2:
        raise ctx.error(key, "polygon is degenerate (zero area: vertices collinear or repeated)")
    normal = newell / area2
    centroid = verts.mean(axis=0)
    dev = np.abs((verts - centroid) @ normal)
    worst = int(np.argmax(dev))
    if dev[worst] > PLANARITY_TOL_M:
        raise ctx.error(
            key,
            f"polygon must be planar (within {PLANARITY_TOL_M:g} m); vertex {worst} is "
            f"{dev[worst]:.3g} m off the plane",
        )
    # 2D frame: u along the axis of the normal's smallest component projected into the plane.
    seed = np.zeros(3)
    seed[int(np.argmin(np.abs(normal)))] = 1.0
    u, v = _plane_axes(normal, seed)
    rel = verts - centroid
    v2d = np.stack([rel @ u, rel @ v], axis=1)
    return PolygonTarget(
        vertices=verts, normal=normal, origin=centroid, u=u, v=v, vertices_2d=v2d, **common
    )


def _target(ctx: _Ctx, raw: Any) -> Target:
    if not isinstance(raw, dict):
        raise ctx.error(None, f"must be a table of keys, got {type(raw).__name__}")
    kind = raw.get("kind")
    if kind is None:
        raise ctx.error("kind", f"missing; allowed: {', '.join(_KIND_KEYS)}")
    if not isinstance(kind, str) or kind not in _KIND_KEYS:  # a list/table kind is unhashable
        raise ctx.error("kind", f"unknown kind {kind!r}; allowed: {', '.join(_KIND_KEYS)}")
    required, optional = _KIND_KEYS[kind]
    allowed = (*_COMMON_KEYS, *required, *optional)
    for k in raw:
        if k not in allowed:
            raise ctx.error(k, f"unknown key for kind {kind!r}; allowed: {', '.join(allowed)}")
    for k in required:
        if k not in raw:
            raise ctx.error(k, f"missing (required for kind {kind!r})")

    refl = _number(ctx, "reflectivity", raw.get("reflectivity", DEFAULT_REFLECTIVITY))
    if refl < 0.0:
        raise ctx.error("reflectivity", f"must be >= 0, got {raw['reflectivity']!r}")
    trans = _number(ctx, "transmission", raw.get("transmission", DEFAULT_TRANSMISSION))
    if not 0.0 <= trans <= 1.0:
        raise ctx.error("transmission", f"must be in [0, 1], got {raw['transmission']!r}")
    vel = _vector(ctx, "velocity", raw.get("velocity", [0.0, 0.0, 0.0]), 3)
    speckle = raw.get("speckle", False)
    if not isinstance(speckle, bool):
        raise ctx.error("speckle", f"must be true or false, got {speckle!r}")
    common: dict[str, Any] = {"reflectivity": refl, "transmission": trans, "velocity": vel,
                              "speckle": speckle}

    if kind == "plane":
        point = _vector(ctx, "point", raw["point"], 3)
        normal = _unit(ctx, "normal", raw["normal"])
        size = None
        if "size" in raw:
            size = _positive_vector(ctx, "size", raw["size"], 2)
        if "up" in raw:
            up = _unit(ctx, "up", raw["up"])
            if _is_parallel(normal, up):
                raise ctx.error("up", "must not be parallel to normal")
        else:
            # Default up = +y; a plane facing along y (floor/ceiling) falls back to +z.
            up = np.array([0.0, 1.0, 0.0])
            if _is_parallel(normal, up):
                up = np.array([0.0, 0.0, 1.0])
        return PlaneTarget(point=point, normal=normal, size=size, up=up, **common)
    if kind == "box":
        center = _vector(ctx, "center", raw["center"], 3)
        size = _positive_vector(ctx, "size", raw["size"], 3)
        rot = _vector(ctx, "rotation_deg", raw.get("rotation_deg", [0.0, 0.0, 0.0]), 3)
        return BoxTarget(center=center, size=size, rotation_deg=rot, **common)
    if kind == "sphere":
        center = _vector(ctx, "center", raw["center"], 3)
        radius = _number(ctx, "radius", raw["radius"])
        if radius <= 0.0:
            raise ctx.error("radius", f"must be > 0, got {raw['radius']!r}")
        return SphereTarget(center=center, radius=radius, **common)
    return _polygon(ctx, raw["vertices"], common)


# --------------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Scene:
    """An immutable list of targets in the sensor frame (see module docstring)."""

    targets: tuple[Target, ...] = ()
    name: str | None = None
    description: str | None = None
    source: str = "<scene>"
    mixed_pixels: bool = True  # sample edge pixels' footprints (sim_devices.world.footprint)

    # -- loading -----------------------------------------------------------------------------------

    @classmethod
    def from_toml(cls, path: str | Path) -> Scene:
        """Load a scene file; every problem (I/O, TOML syntax, content) is a :class:`SceneError`."""
        source = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise SceneError(f"{source}: cannot read scene file: {exc.strerror or exc}") from exc
        return cls.from_toml_text(text, source=source)

    @classmethod
    def from_toml_text(cls, text: str, source: str = "<body>") -> Scene:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SceneError(f"{source}: invalid TOML: {exc}") from exc
        return cls.from_dict(data, source=source)

    @classmethod
    def from_dict(cls, d: Any, source: str = "<dict>") -> Scene:
        """Build from a plain dict (parsed TOML or a JSON body); keys as in the TOML format."""
        ctx = _Ctx(source)
        if not isinstance(d, dict):
            raise ctx.error(None, f"scene must be a table/object, got {type(d).__name__}")
        for k in d:
            if k not in _TOP_KEYS:
                raise ctx.error(k, f"unknown top-level key; allowed: {', '.join(_TOP_KEYS)}")
        name = d.get("name")
        if name is not None and not isinstance(name, str):
            raise ctx.error("name", f"must be a string, got {name!r}")
        description = d.get("description")
        if description is not None and not isinstance(description, str):
            raise ctx.error("description", f"must be a string, got {description!r}")
        mixed = d.get("mixed_pixels", True)
        if not isinstance(mixed, bool):
            raise ctx.error("mixed_pixels", f"must be true or false, got {mixed!r}")
        raw_targets = d.get("target", [])
        if not isinstance(raw_targets, (list, tuple)):
            raise ctx.error("target", "must be an array of tables ([[target]])")
        targets = tuple(_target(_Ctx(source, i), t) for i, t in enumerate(raw_targets))
        return cls(targets=targets, name=name, description=description, source=source,
                   mixed_pixels=mixed)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/TOML friendly) that :meth:`from_dict` turns back into this scene."""
        d: dict[str, Any] = {}
        if self.name is not None:
            d["name"] = self.name
        if self.description is not None:
            d["description"] = self.description
        if not self.mixed_pixels:
            d["mixed_pixels"] = False
        d["target"] = [t.to_dict() for t in self.targets]
        return d

    # -- queries -----------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.targets)

    def moved(self, dt_s: float) -> Scene:
        """The scene ``dt_s`` seconds later: every target translated by ``velocity * dt_s``.

        Velocities are constant; rotations and sizes do not change. Lets a frame-by-frame bench
        move targets on its virtual clock while :meth:`cast` stays a pure geometric query.
        """
        out: list[Target] = []
        for t in self.targets:
            shift = t.velocity * float(dt_s)
            if isinstance(t, PlaneTarget):
                out.append(_replace(t, point=t.point + shift))
            elif isinstance(t, (BoxTarget, SphereTarget)):
                out.append(_replace(t, center=t.center + shift))
            else:
                out.append(_replace(t, vertices=t.vertices + shift, origin=t.origin + shift))
        return Scene(tuple(out), self.name, self.description, self.source, self.mixed_pixels)

    def cast(
        self,
        directions: np.ndarray,
        max_hits: int = 4,
        origin: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Hits:
        """Cast rays from ``origin`` along unit ``directions`` (n, 3); see :func:`raycast.cast`."""
        return cast(self, directions, max_hits=max_hits, origin=origin)

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (n,) of each point (n, 3) to the nearest true target surface (the scores of a
        calibration against the truth;
        :func:`sim_devices.world.surface_truth.surface_distance`)."""
        return surface_truth.surface_distance(self.targets, points)

    def range_error(self, points: np.ndarray, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
        """|p| minus the first-hit range along p's own ray (n,), NaN on a miss
        (:func:`sim_devices.world.surface_truth.range_error`)."""
        return surface_truth.range_error(self, points, origin)


def _replace(t: Target, **changes: Any) -> Target:
    import dataclasses

    return dataclasses.replace(t, **changes)
