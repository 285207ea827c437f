"""Mixed pixels: the beam footprint sampled with sub-rays where it straddles an edge.

A beam of the FPSA scanner is not a ray: behind the lens it is a Gaussian beam whose 1/e^2 radius
grows from the waist ``lambda f / (pi W)`` (capped by the lens aperture f/N) with the geometric
divergence half-angle ``W / (2 f)`` (§4.1.2, eqs. 4-7, 4-9; ``lidard.physics.optics``). Where the
footprint covers a depth discontinuity or a target's edge, a real instrument receives light from
both sides: two weaker returns (depths further apart than a range bin) or one blended return.

The bench decides where (every scene, unless it sets ``mixed_pixels = false``); only what the scene
needs is sampled:

1. every pixel is cast with its central ray (as without footprints);
2. :func:`edge_candidates` flags, per bounded target, the rays that pass within the sampled
   footprint's reach of that target's SILHOUETTE (sphere: the tangent cone; box: between its
   inscribed and bounding spheres; sized plane / polygon: the in-plane distance of the ray's
   crossing to the outline, stretched by 1 / cos(incidence)). Infinite planes have no outline, and
   a target containing the sensor shows no silhouette: a wall, or a room of walls, flags nothing;
3. only those pixels are re-cast with ``SAMPLES`` sub-rays (:func:`sub_rays`). If every
   sample sees the same targets as the central ray (one convex or planar surface: continuous
   depth), the pixel keeps its single ray; otherwise its returns become the groups of samples
   (:mod:`sim_devices.world.mixed_returns`).

The samples are an equal-weight "sunflower" of the Gaussian intensity: sample i sits at radius
``w sqrt(-ln(1 - (i + 1/2) / N) / 2)`` (the (i + 1/2)/N quantile of the power enclosed) and golden
angle i x 137.5 deg, so each carries 1/N of the beam power. Heterodyne detection in the single-mode
receiver (the FPSA is its own receiver, §4.4.1) couples the return field weighted by the
transmitted mode: a return's beat AMPLITUDE scales with the share of beam power on its surface (half
a footprint on an edge: half the amplitude, -6 dB). With N = 16 the sampled share of a straight edge
is within 0.16 of the exact 0.5 erfc(sqrt(2) s / w) (RMS 0.04 over offsets s and orientations).
"""

from __future__ import annotations

import numpy as np

from .targets import BoxTarget, PlaneTarget, PolygonTarget, SphereTarget, Target

__all__ = ["SAMPLES", "SAMPLE_RADII", "REACH", "beam_waist_m", "divergence_half_angle_rad",
           "footprint_radius_m", "edge_candidates", "sub_rays"]

SAMPLES = 16
_I = np.arange(SAMPLES)
#: sample radii in units of the 1/e^2 radius w: equal-power quantiles of the Gaussian
SAMPLE_RADII = np.sqrt(-np.log(1.0 - (_I + 0.5) / SAMPLES) / 2.0)
SAMPLE_ANGLES = _I * np.pi * (3.0 - np.sqrt(5.0))   # golden angle: no two samples line up
#: the outermost sample's radius / w: how far from an outline a footprint can see across it
REACH = float(SAMPLE_RADII.max())


def beam_waist_m(*, emission_w_m: float, focal_m: float, wavelength_m: float, aperture_m: float) -> float:
    """1/e^2 radius of the beam leaving the lens: lambda f / (pi W), capped at half the aperture."""
    return min(wavelength_m * focal_m / (np.pi * emission_w_m), 0.5 * aperture_m)


def divergence_half_angle_rad(*, emission_w_m: float, focal_m: float) -> float:
    """Geometric divergence half-angle of a beam: W / (2 f) (§4.1.2, eq. 4-9)."""
    return 0.5 * emission_w_m / focal_m


def footprint_radius_m(range_m: np.ndarray, *, emission_w_m: float, focal_m: float,
                       wavelength_m: float, aperture_m: float) -> np.ndarray:
    """1/e^2 beam radius at ``range_m``: waist (<= aperture / 2) + range x divergence half-angle."""
    waist = beam_waist_m(emission_w_m=emission_w_m, focal_m=focal_m, wavelength_m=wavelength_m,
                         aperture_m=aperture_m)
    half = divergence_half_angle_rad(emission_w_m=emission_w_m, focal_m=focal_m)
    return waist + np.asarray(range_m, np.float64) * half


# -- silhouettes ---------------------------------------------------------------------------------------

def _near_sphere(d, c, r, reach_at):
    along = d @ c
    if float(c @ c) <= r * r:
        return np.zeros(len(d), bool)          # inside: the far wall, no outline
    perp = np.sqrt(np.maximum(float(c @ c) - along**2, 0.0))
    return (along > 0) & (np.abs(perp - r) <= reach_at(np.maximum(along, 0.0)))


def _slab_hit(o_l: np.ndarray, d_l: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Rays (box frame: origin o_l (3,), directions d_l (n, 3)) that meet the box of half-sizes
    ``half`` (n, 3) ahead of the origin (slab method)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o_l) / d_l, (half - o_l) / d_l
    par = d_l == 0.0
    inside = np.abs(o_l) <= half
    lo = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
    hi = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
    return (lo <= hi) & (hi > 0)


def _near_box(d, t: BoxTarget, reach_at):
    o_l = -t.center @ t.rotation                 # the sensor in the box frame
    half = 0.5 * t.size
    if np.all(np.abs(o_l) <= half):
        return np.zeros(len(d), bool)            # inside: continuous walls
    along = d @ t.center
    # the footprint is widest at the box's far side
    reach = reach_at(np.maximum(along, 0.0) + float(np.linalg.norm(half)))[:, None]
    d_l = d @ t.rotation
    grown = _slab_hit(o_l, d_l, half + reach)
    # a ray through the box shrunk by the reach keeps every sample (displaced <= reach) on the box
    shrunk = _slab_hit(o_l, d_l, np.maximum(half - reach, 0.0)) & np.all(half > reach, axis=1)
    return grown & ~shrunk


def _crossing(d, point, normal):
    """Range to the plane and |cos(incidence)| per ray; inf where the plane is not ahead."""
    denom = d @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(point @ normal) / denom
    t = np.where((denom != 0) & (t > 0), t, np.inf)
    return t, np.abs(denom)


def _near_outline(d, point, normal, u, v, reach_at, outline_dist):
    t, cos = _crossing(d, point, normal)
    ok = np.flatnonzero(np.isfinite(t))
    out = np.zeros(len(d), bool)
    if ok.size == 0:
        return out
    rel = t[ok, None] * d[ok] - point
    # a footprint of radius w is stretched to w / cos across a tilted surface (cos floored: grazing)
    reach = reach_at(t[ok]) / np.maximum(cos[ok], 0.05)
    out[ok] = outline_dist(rel @ u, rel @ v, reach)
    return out


def _rect_near(size):
    def near(x, y, reach):
        dx, dy = np.abs(x) - 0.5 * size[0], np.abs(y) - 0.5 * size[1]
        outside = np.hypot(np.maximum(dx, 0), np.maximum(dy, 0))
        inside = np.minimum(-dx, -dy)
        return np.where((dx > 0) | (dy > 0), outside, inside) <= reach
    return near


def _poly_near(v2d):
    r_max = float(np.sqrt(np.max(np.sum(v2d**2, axis=1))))
    a, b = v2d, np.roll(v2d, -1, axis=0)
    ab = b - a
    ab2 = np.maximum(np.sum(ab**2, axis=1), 1e-300)

    def near(x, y, reach):
        out = np.zeros(len(x), bool)
        cand = np.flatnonzero(np.hypot(x, y) <= r_max + reach)   # cull by the bounding circle
        if cand.size == 0:
            return out
        q = np.stack([x[cand], y[cand]], axis=1)[:, None, :]       # (k, 1, 2)
        s = np.clip(np.sum((q - a) * ab, axis=2) / ab2, 0.0, 1.0)  # (k, m): nearest point on each edge
        dist = np.linalg.norm(q - (a + s[..., None] * ab), axis=2).min(axis=1)
        out[cand] = dist <= reach[cand]
        return out
    return near


def _near_target(t: Target, d: np.ndarray, reach_at) -> np.ndarray | None:
    if isinstance(t, SphereTarget):
        return _near_sphere(d, t.center, float(t.radius), reach_at)
    if isinstance(t, BoxTarget):
        return _near_box(d, t, reach_at)
    if isinstance(t, PlaneTarget):
        if t.size is None:
            return None                            # an infinite plane has no outline
        u, v = t.axes
        return _near_outline(d, t.point, t.normal, u, v, reach_at, _rect_near(t.size))
    if isinstance(t, PolygonTarget):
        return _near_outline(d, t.origin, t.normal, t.u, t.v, reach_at, _poly_near(t.vertices_2d))
    raise TypeError(f"edge_candidates: unknown target type {type(t).__name__}")


def edge_candidates(targets, directions: np.ndarray, radius_at) -> np.ndarray:
    """Rays (n, 3) from the origin whose sampled footprint may cross the outline of a bounded
    target; ``radius_at(range_m)`` gives the footprint's 1/e^2 radius there."""
    out = np.zeros(directions.shape[0], bool)

    def reach_at(r):
        return REACH * radius_at(r) * 1.02 + 1e-9   # 2 %: ranges along a sub-ray vs the central one

    for t in targets:
        near = _near_target(t, directions, reach_at)
        if near is not None:
            out |= near
    return out


def sub_rays(directions: np.ndarray, waist_m: float, half_angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions, each (n, SAMPLES, 3), of the footprint samples of rays (n, 3):
    sample i leaves the lens at ``rho_i waist`` off the axis and diverges by ``rho_i half_angle``
    along the same transverse direction, so at range r it is ``rho_i (waist + r half_angle)`` =
    ``rho_i w(r)`` off the central ray (:func:`footprint_radius_m`'s beam; near the lens the waist
    dominates: a 1 m footprint is mostly the waist, not a cone from the lens centre)."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    e = (np.cos(SAMPLE_ANGLES)[None, :, None] * u[:, None, :]
         + np.sin(SAMPLE_ANGLES)[None, :, None] * v[:, None, :])          # (n, N, 3) transverse
    rho = SAMPLE_RADII[None, :, None]
    origins = rho * waist_m * e
    out = d[:, None, :] + rho * np.tan(half_angle_rad) * e
    return origins, out / np.linalg.norm(out, axis=2, keepdims=True)
