"""Scores of measured points against a scene's TRUE surfaces.

The scan's (x, y, z) come from the daemon's pointing model; the scene knows where the surfaces
really are. Two scores, both from the scene alone (no pointing model, no bench):

* :func:`surface_distance`: for every point, the distance to the nearest true surface of any
  target (:mod:`lidard.physics.surfaces`), the x/y/z error a pointing error shows as (a point
  displaced sideways off a letter is at its in-plane distance to the letter's edge);
* :func:`range_error`: measured range |p| minus the range at which the ray from the lens centre
  through p first meets the scene (NaN where that ray misses everything): the error along the
  beam, as the daemon believes the beam points.

Against the bench's own truth per pixel (``World.ground_truth``, the range along the TRUE beam),
the range error isolates range calibration (MZI delay, zero offset) from pointing.
:meth:`sim_devices.world.scene.Scene.surface_distance` and :meth:`~Scene.range_error` call these.
"""

from __future__ import annotations

import numpy as np

from lidard.physics import surfaces as sf
from sim_devices.world.targets import BoxTarget, PlaneTarget, PolygonTarget, SphereTarget, Target

__all__ = ["target_distance", "surface_distance", "range_error"]


def target_distance(target: Target, points: np.ndarray) -> np.ndarray:
    """Unsigned distance of points (n, 3) to one target's surface."""
    if isinstance(target, PlaneTarget):
        return sf.distance_to_plane(points, target.point, target.normal, size=target.size, up=target.up)
    if isinstance(target, SphereTarget):
        return sf.distance_to_sphere(points, target.center, target.radius)
    if isinstance(target, BoxTarget):
        return sf.distance_to_box(points, target.center, target.size, target.rotation)
    if isinstance(target, PolygonTarget):
        return sf.distance_to_polygon(points, target.vertices)
    raise TypeError(f"target_distance: unknown target type {type(target).__name__}")


def surface_distance(targets, points) -> np.ndarray:
    """Min distance (n,) of each point to any target's surface (inf for an empty scene)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    for t in targets:
        np.minimum(out, target_distance(t, p), out=out)
    return out


def range_error(scene, points, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """|p - origin| minus the first-hit range along (p - origin) (n,); NaN where the ray misses."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    rel = p - o
    r = np.linalg.norm(rel, axis=1)
    ok = r > 0
    out = np.full(len(p), np.nan)
    if ok.any():
        hits = scene.cast(rel[ok] / r[ok, None], max_hits=1, origin=o)
        first = hits.range_m[:, 0]
        out[ok] = np.where(np.isfinite(first), r[ok] - first, np.nan)
    return out
