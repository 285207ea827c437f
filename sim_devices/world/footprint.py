"""Mixed pixels: the beam footprint sampled with sub-rays where it straddles an edge (issue 15).

A beam of the FPSA scanner is not a ray: behind the lens it is a Gaussian beam whose radius grows
from the waist ``lambda f / (pi W)`` (capped by the lens aperture f/N) with the geometric
divergence half-angle ``W / (2 f)`` (§4.1.2, eqs. 4-7, 4-9; ``lidard.physics.optics``). Where the
footprint covers a depth discontinuity or a target's edge, a real instrument receives light from
both sides: two weaker returns (depths further apart than a range bin) or one blended return.

Only what the scene needs is sampled: every pixel is first cast with its central ray; only pixels
whose central ray passes within (bounding radius + footprint) of a bounded target (a finite plane,
box, sphere or polygon) are re-cast with ``RING`` sub-rays on a ring at ``RING_FRACTION`` of the
footprint radius. If all samples agree (same first target, ranges within one range bin) the pixel
keeps its single ray; otherwise its returns become the groups of samples by (target, range bin),
each with an amplitude weight equal to its share of the samples (heterodyne detection sums FIELDS
over the footprint, so a half-covered return gives half the beat amplitude, -6 dB). A scene of
infinite planes casts no sub-ray at all: its cost is that of the single-ray cast.
"""

from __future__ import annotations

import numpy as np

from .targets import BoxTarget, PlaneTarget, PolygonTarget, SphereTarget, Target

__all__ = ["RING", "RING_FRACTION", "footprint_radius_m", "edge_candidates", "sub_ray_directions",
           "mix_samples"]

RING = 6                 # sub-rays on the ring (plus the central ray: 7 samples)
RING_FRACTION = 0.7      # ring radius / 1/e^2 radius: the samples split a Gaussian's power evenly


def footprint_radius_m(range_m: np.ndarray, *, emission_w_m: float, focal_m: float,
                       wavelength_m: float, aperture_m: float) -> np.ndarray:
    """1/e^2 beam radius at ``range_m``: waist (<= aperture / 2) + range x divergence half-angle."""
    waist = min(wavelength_m * focal_m / (np.pi * emission_w_m), 0.5 * aperture_m)
    return waist + np.asarray(range_m, np.float64) * (0.5 * emission_w_m / focal_m)


def _bounding_sphere(t: Target) -> tuple[np.ndarray, float] | None:
    if isinstance(t, PlaneTarget):
        return None if t.size is None else (t.point, 0.5 * float(np.hypot(*t.size)))
    if isinstance(t, BoxTarget):
        return t.center, 0.5 * float(np.linalg.norm(t.size))
    if isinstance(t, SphereTarget):
        return t.center, float(t.radius)
    if isinstance(t, PolygonTarget):
        return t.origin, float(np.sqrt(np.max(np.sum(t.vertices_2d**2, axis=1))))
    return None


def edge_candidates(targets, directions: np.ndarray, radius_at) -> np.ndarray:
    """Rays (n, 3) from the origin whose footprint may touch the edge of a bounded target: the
    ray passes within bounding radius + footprint radius of the target's bounding-sphere centre.
    ``radius_at(range_m)`` gives the footprint radius."""
    out = np.zeros(directions.shape[0], bool)
    for t in targets:
        bs = _bounding_sphere(t)
        if bs is None:
            continue
        c, r = bs
        along = directions @ c
        perp = np.sqrt(np.maximum(float(c @ c) - along**2, 0.0))
        out |= (along > -r) & (perp <= r + radius_at(np.maximum(along, 0.0)))
    return out


def sub_ray_directions(directions: np.ndarray, half_angle_rad: np.ndarray) -> np.ndarray:
    """(n, RING, 3) unit directions on a cone of ``RING_FRACTION * half_angle`` around each ray."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    phi = 2 * np.pi * np.arange(RING) / RING
    a = np.tan(RING_FRACTION * np.asarray(half_angle_rad))[:, None, None]
    out = d[:, None, :] + a * (np.cos(phi)[None, :, None] * u[:, None, :]
                               + np.sin(phi)[None, :, None] * v[:, None, :])
    return out / np.linalg.norm(out, axis=2, keepdims=True)


def mix_samples(samples: list[tuple], bin_m: float, max_hits: int) -> tuple | None:
    """Combine per-sample hit tuples (range, incidence, reflectivity, velocity, transmission,
    target) of one pixel into weighted returns; None when every sample sees the same first surface
    within one range bin (the pixel keeps its central ray)."""
    firsts = [(int(s[5][0]), float(s[0][0])) if len(s[0]) else (-1, np.inf) for s in samples]
    t0, r0 = firsts[0]
    if all(t == t0 and (t < 0 or abs(r - r0) < bin_m) for t, r in firsts):
        return None
    hits = sorted(((int(s[5][k]), float(s[0][k]), [float(c[k]) for c in s])
                   for s in samples for k in range(len(s[0]))), key=lambda h: (h[0], h[1]))
    groups: list[list] = []
    for i, (t, r, vals) in enumerate(hits):
        # a new return where the target changes or the depth jumps by more than a range bin
        if i == 0 or t != hits[i - 1][0] or r - hits[i - 1][1] > bin_m:
            groups.append([])
        groups[-1].append(vals)
    rows = sorted(([*np.mean(g, axis=0)[:6], len(g) / len(samples)] for g in groups),
                  key=lambda r: r[0])[:max_hits]
    cols = np.array(rows, np.float64).T
    return tuple(cols[j].copy() for j in range(7))
