"""Distances from points to the surfaces of known targets: planes, spheres, boxes, planar polygons.

Pure numpy. Used to score a point cloud without trusting the pointing model (the
point-to-surface distance of each measured (x, y, z) to the scene's true surfaces, not only the
range along the beam), and by calibrations that fit geometry to points on known targets (a plate
on a rail: :func:`distance_to_plane`; reference spheres: :func:`distance_to_sphere`).

Every function takes ``points`` of shape (n, 3) (or (3,)) in one frame (the sensor frame of
dissertation §4.4, metres) and returns distances of shape (n,) (or a scalar-shaped array).
Distances are unsigned (>= 0) unless ``signed=True``, where the sign says which side of the
surface a point is on (positive: the side the normal points to, outside a sphere or box); for a
finite plane or a polygon a signed distance carries the side of the infinite plane.

The solids are surfaces, not volumes: a point inside a box or sphere is at the distance to its
nearest face, as a LiDAR return lies on the skin of what it hits.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["distance_to_plane", "distance_to_sphere", "distance_to_box", "distance_to_polygon",
           "polygon_normal"]


def _points(points: ArrayLike) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise ValueError(f"points must have shape (n, 3) or (3,), got {p.shape}")
    return p


def _unit(v: ArrayLike, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {v.tolist()}")
    return v / n


def _in_plane_axes(normal: np.ndarray, up: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(u, v): v = ``up`` projected into the plane (default +y, or +z for a plane facing along y),
    u = v x n; the convention of the scene files' finite planes (sim_devices.world.targets)."""
    if up is None:
        up = np.array([0.0, 1.0, 0.0])
        if np.linalg.norm(np.cross(normal, up)) < 1e-9:
            up = np.array([0.0, 0.0, 1.0])
    up = _unit(up, "up")
    v = up - np.dot(up, normal) * normal
    if np.linalg.norm(v) < 1e-9:
        raise ValueError("up must not be parallel to the plane's normal")
    v /= np.linalg.norm(v)
    u = np.cross(v, normal)
    return u / np.linalg.norm(u), v


def distance_to_plane(points: ArrayLike, origin: ArrayLike, normal: ArrayLike, *,
                      size: tuple[float, float] | np.ndarray | None = None, up: ArrayLike | None = None, signed: bool = False) -> np.ndarray:
    """Distance to the plane through ``origin`` with normal ``normal`` (any length).

    ``size = (w, h)``: only the w x h rectangle centred on ``origin`` (h along ``up`` projected into
    the plane, w across it; default up +y, as the scene files' finite planes): a point beside the
    rectangle is at the distance to its nearest edge, sqrt(d_perp^2 + d_in_plane^2).
    """
    p = _points(points)
    n = _unit(normal, "normal")
    rel = p - np.asarray(origin, dtype=np.float64).reshape(3)
    perp = rel @ n
    if size is None:
        return perp if signed else np.abs(perp)
    w, h = (float(s) for s in size)
    if not (w > 0 and h > 0):
        raise ValueError(f"size must be two positive lengths (w, h), got {list(size)}")
    u, v = _in_plane_axes(n, up)
    du = np.maximum(np.abs(rel @ u) - w / 2.0, 0.0)
    dv = np.maximum(np.abs(rel @ v) - h / 2.0, 0.0)
    d = np.sqrt(perp * perp + du * du + dv * dv)
    return np.where(perp < 0, -d, d) if signed else d


def distance_to_sphere(points: ArrayLike, centre: ArrayLike, radius: float, *, signed: bool = False) -> np.ndarray:
    """Distance to a sphere's surface: | |p - c| - r | (signed: positive outside)."""
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be > 0, got {radius!r}")
    p = _points(points)
    d = np.linalg.norm(p - np.asarray(centre, dtype=np.float64).reshape(3), axis=-1) - float(radius)
    return d if signed else np.abs(d)


def distance_to_box(points: ArrayLike, centre: ArrayLike, size: ArrayLike, rotation: ArrayLike | None = None, *, signed: bool = False) -> np.ndarray:
    """Distance to the skin of an oriented box: full edge lengths ``size`` (3,), ``rotation`` a 3x3
    matrix mapping box-local to the points' frame (None: axis-aligned). Signed: positive outside.

    In box-local coordinates q, with e = |q| - size/2 per axis, the signed distance is
    |max(e, 0)| + min(max_i e_i, 0) (outside: to the nearest point of the box; inside: minus the
    distance to the nearest face)."""
    p = _points(points)
    half = np.asarray(size, dtype=np.float64).reshape(3) / 2.0
    if not np.all(half > 0):
        raise ValueError(f"size must be three positive lengths, got {np.asarray(size).tolist()}")
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-9):
        raise ValueError("rotation must be a 3x3 orthonormal matrix")
    q = (p - np.asarray(centre, dtype=np.float64).reshape(3)) @ r   # row-vector form of R^T (p - c)
    e = np.abs(q) - half
    d = np.linalg.norm(np.maximum(e, 0.0), axis=-1) + np.minimum(np.max(e, axis=-1), 0.0)
    return d if signed else np.abs(d)


def polygon_normal(vertices: ArrayLike) -> np.ndarray:
    """Unit normal of a planar polygon by Newell's method (its sense follows the vertex order)."""
    vtx = np.asarray(vertices, dtype=np.float64)
    if vtx.ndim != 2 or vtx.shape[1] != 3 or len(vtx) < 3:
        raise ValueError(f"vertices must have shape (m >= 3, 3), got {vtx.shape}")
    nxt = np.roll(vtx, -1, axis=0)
    newell = np.array([np.sum((vtx[:, 1] - nxt[:, 1]) * (vtx[:, 2] + nxt[:, 2])),
                       np.sum((vtx[:, 2] - nxt[:, 2]) * (vtx[:, 0] + nxt[:, 0])),
                       np.sum((vtx[:, 0] - nxt[:, 0]) * (vtx[:, 1] + nxt[:, 1]))])
    return _unit(newell, "the polygon's normal (vertices collinear?)")


def _inside_2d(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule: is each 2-D point of q (n, 2) inside the polygon poly (m, 2)?"""
    a, b = poly, np.roll(poly, -1, axis=0)
    y = q[:, 1:2]
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    dy = np.where(b[:, 1] == a[:, 1], 1.0, b[:, 1] - a[:, 1])
    x_at = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / dy
    return (np.count_nonzero(crosses & (q[:, 0:1] < x_at), axis=1) % 2) == 1


def _edge_distance_2d(q: np.ndarray, poly: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Distance of each 2-D point of q (n, 2) to the nearest edge segment of poly (m, 2)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a                                                    # (m, 2)
    len2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    out = np.empty(len(q))
    for i in range(0, len(q), chunk):   # (chunk, m, 2) temporaries: bounded memory for big clouds
        ap = q[i:i + chunk, None, :] - a[None, :, :]
        t = np.clip(np.einsum("nmk,mk->nm", ap, ab) / len2, 0.0, 1.0)
        diff = ap - t[:, :, None] * ab[None, :, :]
        out[i:i + chunk] = np.sqrt(np.min(np.sum(diff * diff, axis=2), axis=1))
    return out


def distance_to_polygon(points: ArrayLike, vertices: ArrayLike, *, signed: bool = False) -> np.ndarray:
    """Distance to a planar polygon (m, 3) vertices, possibly non-convex (inside: even-odd rule).

    A point whose projection falls inside is at its perpendicular distance; one outside at
    sqrt(d_perp^2 + d_edge^2), d_edge the in-plane distance to the nearest edge. Signed: the sign
    of the side of the plane (Newell normal of the vertex order)."""
    p = _points(points)
    flat = p.reshape(-1, 3)
    vtx = np.asarray(vertices, dtype=np.float64)
    n = polygon_normal(vtx)
    origin = vtx.mean(axis=0)
    u, v = _in_plane_axes(n, np.eye(3)[int(np.argmin(np.abs(n)))])
    poly = np.stack([(vtx - origin) @ u, (vtx - origin) @ v], axis=1)
    rel = flat - origin
    perp = rel @ n
    q = np.stack([rel @ u, rel @ v], axis=1)
    out = np.abs(perp)
    outside = ~_inside_2d(q, poly)
    if outside.any():
        edge = _edge_distance_2d(q[outside], poly)
        out[outside] = np.hypot(perp[outside], edge)
    if signed:
        out = np.where(perp < 0, -out, out)
    return out.reshape(p.shape[:-1])
