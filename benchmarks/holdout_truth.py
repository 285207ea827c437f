"""Analytic truth for the motion hold-out scenes (issue 14, first Done-when; benchmarks/motion_holdout.py).

Written from the scene format's documentation only (sim_devices/world/scene.py's docstring, the scene
files), independently of the bench's ray caster, so that the hold-out check does not score the DSP
against the code it is tested with: every target is translated to a point's own time t (positions in
the file are those at t = 0, the scan's first trigger; constant velocity), and the beam
(sensor-frame unit direction from the lens centre, eq. 4-1 of the dissertation, taken from the nominal
optics) is intersected with it in closed form. The radial velocity of a hit is direction . velocity
(positive receding): the Doppler term of every scatterer of a rigidly translating target (§2.1.2).

Supported kinds: plane (infinite, or a rectangle of ``size`` about ``point`` with ``up``), sphere,
box (``rotation_deg`` extrinsic about x, then y, then z) and planar polygon (convex or not). Transmission
is honoured: surfaces along a ray up to and including the first opaque one are visible.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Surface:
    """One target of a hold-out scene, at scene time 0."""

    index: int
    kind: str
    params: dict
    velocity: np.ndarray
    transmission: float


def load(path: str | Path) -> list[Surface]:
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    out = []
    for i, t in enumerate(data.get("target", [])):
        out.append(Surface(i, t["kind"], t, np.asarray(t.get("velocity", [0.0, 0.0, 0.0]), float),
                           float(t.get("transmission", 0.0))))
    return out


def _rot(deg) -> np.ndarray:
    rx, ry, rz = np.radians(np.asarray(deg, float))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return mz @ my @ mx


def _plane(d, shift, p):
    """Range along unit rays d (n, 3) to a plane moved by shift (n, 3); NaN on a miss."""
    n = np.asarray(p["normal"], float)
    n = n / np.linalg.norm(n)
    q = np.asarray(p["point"], float) + shift
    den = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.einsum("nj,j->n", q, n) / den
    r = np.where((np.abs(den) > 1e-12) & (r > 0), r, np.nan)
    if "size" not in p:
        return r
    up = np.asarray(p.get("up", [0.0, 1.0, 0.0] if abs(n[1]) < 0.999999 else [0.0, 0.0, 1.0]), float)
    v_ax = up - (up @ n) * n
    v_ax /= np.linalg.norm(v_ax)
    u_ax = np.cross(v_ax, n)
    rel = d * r[:, None] - q
    w, h = p["size"]
    inside = (np.abs(rel @ u_ax) <= w / 2) & (np.abs(rel @ v_ax) <= h / 2)
    return np.where(inside, r, np.nan)


def _sphere(d, shift, p):
    c = np.asarray(p["center"], float) + shift
    b = np.einsum("nj,nj->n", d, c)
    disc = b * b - (np.einsum("nj,nj->n", c, c) - float(p["radius"]) ** 2)
    with np.errstate(invalid="ignore"):
        r = b - np.sqrt(disc)
    return np.where((disc >= 0) & (r > 0), r, np.nan)


def _box(d, shift, p):
    """Slab test in the box's own frame (R maps box-local to sensor)."""
    rot = _rot(p.get("rotation_deg", [0.0, 0.0, 0.0]))
    c = np.asarray(p["center"], float) + shift
    o_loc = (-c) @ rot            # origin (0,0,0) in box coordinates: R^T (0 - c)
    d_loc = d @ rot
    half = np.asarray(p["size"], float) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o_loc) / d_loc
        t2 = (half - o_loc) / d_loc
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((near <= far) & (near > 0), near, np.nan)


def _polygon(d, shift, p):
    """Planar polygon, convex or not: plane hit, then inside by the even-odd rule (a ray from the hit
    along the plane crosses the outline an odd number of times), in coordinates of the plane."""
    v = np.asarray(p["vertices"], float)
    # Newell's normal: the outline's area vector, whatever vertices are collinear or where it is not convex
    n = np.cross(v - v.mean(axis=0), np.roll(v, -1, axis=0) - v.mean(axis=0)).sum(axis=0)
    n /= np.linalg.norm(n)
    r = _plane(d, shift, {"point": v[0], "normal": n})
    hit = d * r[:, None] - shift
    u = v[1] - v[0]
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    hx, hy = (hit - v[0]) @ u, (hit - v[0]) @ w
    px, py = (v - v[0]) @ u, (v - v[0]) @ w
    inside = np.zeros(len(d), bool)
    for (ax, ay), (bx, by) in zip(zip(px, py), zip(np.roll(px, -1), np.roll(py, -1))):
        spans = (ay > hy) != (by > hy)                # the edge crosses the hit's horizontal line
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (hy - ay) * (bx - ax) / (by - ay)
        inside ^= spans & (hx < x_cross)
    return np.where(inside, r, np.nan)


_KINDS = {"plane": _plane, "sphere": _sphere, "box": _box, "polygon": _polygon}


def ranges(surfaces: list[Surface], d: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """(n, k) range along each ray d (n, 3) to each target k at the ray's own time t_s (n,); NaN: miss."""
    t_s = np.broadcast_to(np.asarray(t_s, float), (len(d),))
    cols = [_KINDS[s.kind](d, np.outer(t_s, s.velocity), s.params) for s in surfaces]
    return np.stack(cols, axis=1) if cols else np.zeros((len(d), 0))


def _normal(s: Surface, hit: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Unit surface normal (n, 3) of target s at hit points (n, 3) (the target moved by shift)."""
    p = s.params
    if s.kind == "sphere":
        n = hit - (np.asarray(p["center"], float) + shift)
    elif s.kind == "box":
        rot = _rot(p.get("rotation_deg", [0.0, 0.0, 0.0]))
        loc = (hit - (np.asarray(p["center"], float) + shift)) @ rot
        face = np.argmax(np.abs(loc) / (np.asarray(p["size"], float) / 2), axis=1)
        n = rot[:, face].T
    elif s.kind == "plane":
        n = np.broadcast_to(np.asarray(p["normal"], float), hit.shape)
    else:
        v = np.asarray(p["vertices"], float)
        n = np.broadcast_to(np.cross(v[1] - v[0], v[2] - v[0]), hit.shape)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def incidence_rad(surfaces: list[Surface], d: np.ndarray, t_s: np.ndarray, rng: np.ndarray) -> np.ndarray:
    """(n, k) angle between ray d and target k's normal at its hit (NaN on a miss): a Lambertian
    return falls as its cosine, so a beam grazing a face (> 80 deg) is an SNR question, not motion."""
    t_s = np.broadcast_to(np.asarray(t_s, float), (len(d),))
    out = np.full(rng.shape, np.nan)
    for k, s in enumerate(surfaces):
        hit = d * np.nan_to_num(rng[:, k])[:, None]
        n = _normal(s, hit, np.outer(t_s, s.velocity))
        cos = np.clip(np.abs(np.einsum("nj,nj->n", n, d)), 0.0, 1.0)
        out[:, k] = np.where(np.isfinite(rng[:, k]), np.arccos(cos), np.nan)
    return out


def visible(surfaces: list[Surface], rng: np.ndarray) -> np.ndarray:
    """(n, k) True where target k is seen along the ray: hit, and no opaque target in front."""
    r = np.where(np.isnan(rng), np.inf, rng)
    opaque = np.array([s.transmission == 0.0 for s in surfaces])
    first_opaque = np.min(np.where(opaque[None, :], r, np.inf), axis=1)
    return np.isfinite(r) & (r <= first_opaque[:, None])


def radial_velocity(surfaces: list[Surface], d: np.ndarray) -> np.ndarray:
    """(n, k) radial velocity of target k along ray d, positive receding."""
    return d @ np.stack([s.velocity for s in surfaces], axis=1)
