"""Vectorized ray casting into a scene's targets (numpy, no loop over rays).

Builds on the target types of :mod:`sim_devices.world.targets` only; the scene loader imports
this module (``Scene.cast``), never the reverse.

Used by the simulated bench to find, for every beam direction of the FPSA scanner (eq. 4-1:
antenna offset (x, y) behind a lens of focal length f -> direction (-x/f, -y/f, 1) normalised),
what the beam hits: range, incidence angle, albedo, radial velocity and the one-way power fraction
that reaches each hit through partially transmissive targets in front of it. The link budget
(§2.4, §4.4) and the beat synthesis turn these into beat tones; that is not done here.

Per target kind, each target gives at most one hit per ray, the nearest surface point strictly
ahead of the origin (range > 0; hits at range <= 0, i.e. at or behind the sensor, are ignored):

* plane: ray-plane intersection; with ``size``, only inside the w x h rectangle.
* polygon: ray-plane intersection, then point-in-polygon by the even-odd crossing rule in the
  polygon's own 2D frame, vectorized over rays and edges (non-convex letters work).
* box: slab method in the box frame. From outside the ray enters once: the entry face is returned.
  A box behind the origin gives nothing. A box *containing* the origin gives its exit face (the
  nearest surface point ahead, as seen from inside), which is consistent with the sphere below.
* sphere: nearest positive root of |o + t d - c| = r (from inside: the far wall).

Ordering and ties: hits are sorted by range; hits whose ranges are chained within
``TIE_TOL_M`` = 1e-9 m of each other (a letter lying on its background plane, coplanar pieces)
count as one tie group and are ordered by target index, so the first listed target wins. Inside a
tie group the reported ranges may therefore be out of order by less than 1e-9 m.

Transmission: ``transmission[k]`` is the product of the ``transmission`` of all targets hit before
hit k (one-way; 1 for the first hit). Hits behind an opaque target (transmission 0) are dropped,
so a ray returns at most one hit on or after its first opaque target.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim_devices.world.targets import (
    BoxTarget,
    PlaneTarget,
    PolygonTarget,
    SphereTarget,
    Target,
)


class _HasTargets(Protocol):
    """What :func:`cast` needs of a scene: its targets (a Scene, or anything listing targets)."""

    @property
    def targets(self) -> Sequence[Target]: ...

__all__ = ["Hits", "RayError", "cast", "intersect_target", "TIE_TOL_M", "UNIT_TOL"]

#: Ranges closer than this (m) are a tie, resolved in favour of the first listed target.
TIE_TOL_M = 1e-9
#: Allowed deviation of |direction| from 1.
UNIT_TOL = 1e-6


class RayError(ValueError):
    """Bad arguments to :func:`cast` (shape, non-finite or non-unit directions, max_hits)."""


@dataclass(frozen=True)
class Hits:
    """Ray-cast result; every array has shape (n, max_hits) except ``count`` (n,).

    Slots past ``count[i]`` are empty: ``range_m`` = inf, ``target_index`` = -1, ``incidence_rad``
    = nan, ``reflectivity`` = ``radial_velocity_mps`` = ``transmission`` = 0, ``points_m`` = nan.
    """

    range_m: np.ndarray  # float64, along the unit direction from the origin
    incidence_rad: np.ndarray  # angle between ray and surface normal, [0, pi/2]
    reflectivity: np.ndarray  # Lambertian albedo of the hit target
    radial_velocity_mps: np.ndarray  # v . d, positive = receding
    transmission: np.ndarray  # one-way power fraction reaching this hit
    target_index: np.ndarray  # int64, index into scene.targets, -1 = none
    count: np.ndarray  # (n,) int64 valid hits per ray
    points_m: np.ndarray  # (n, max_hits, 3) hit positions in the sensor frame

    @property
    def max_hits(self) -> int:
        return int(self.range_m.shape[1])


# --------------------------------------------------------------------------------------------------
# Per-kind kernels: (o (3,), d (n,3)) -> (t (n,), normal (n,3) or (3,)), t = inf on a miss
# --------------------------------------------------------------------------------------------------


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product; either side may be one (3,) vector shared by every row."""
    return np.einsum("...j,...j->...", a, b)


def _plane_t(o: np.ndarray, d: np.ndarray, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    denom = d @ normal
    num = (point - o) @ normal            # scalar, or one per ray for per-ray origins (n, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / denom
    # Parallel rays (denom == 0) never hit; t <= 0 is at or behind the origin.
    return np.where((denom != 0.0) & (t > 0.0), t, np.inf)


def _cast_plane(o: np.ndarray, d: np.ndarray, tg: PlaneTarget) -> tuple[np.ndarray, np.ndarray]:
    t = _plane_t(o, d, tg.point, tg.normal)
    if tg.size is not None:
        u, v = tg.axes
        finite = np.isfinite(t)
        ts = np.where(finite, t, 0.0)
        rel = o - tg.point + ts[:, None] * d
        inside = (np.abs(rel @ u) <= 0.5 * tg.size[0]) & (np.abs(rel @ v) <= 0.5 * tg.size[1])
        t = np.where(finite & inside, t, np.inf)
    return t, np.broadcast_to(tg.normal, d.shape)


def _cast_polygon(
    o: np.ndarray, d: np.ndarray, tg: PolygonTarget
) -> tuple[np.ndarray, np.ndarray]:
    t = _plane_t(o, d, tg.origin, tg.normal)
    normal = np.broadcast_to(tg.normal, d.shape)
    finite = np.isfinite(t)
    ts = np.where(finite, t, 0.0)
    rel = o - tg.origin + ts[:, None] * d
    px_all, py_all = rel @ tg.u, rel @ tg.v
    # Cull: only rays landing inside the bounding circle of the vertices need the (n, m) edge test;
    # for a letter in a wide scan that is a small fraction of the rays.
    r2 = float(np.max(np.einsum("ij,ij->i", tg.vertices_2d, tg.vertices_2d)))
    cand = np.flatnonzero(finite & (px_all * px_all + py_all * py_all <= r2))
    out = np.full(d.shape[0], np.inf)
    if cand.size == 0:
        return out, normal
    px, py = px_all[cand, None], py_all[cand, None]  # (k, 1)
    xi, yi = tg.vertices_2d[:, 0], tg.vertices_2d[:, 1]  # (m,)
    xj, yj = np.roll(xi, 1), np.roll(yi, 1)
    # Even-odd rule: count edges that straddle the horizontal line y = py to the right of px.
    straddle = (yi > py) != (yj > py)  # (k, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = xi + (py - yi) * ((xj - xi) / (yj - yi))
    crossings = np.count_nonzero(straddle & (px < x_cross), axis=1)
    inside = (crossings % 2) == 1
    out[cand[inside]] = t[cand[inside]]
    return out, normal


def _cast_box(o: np.ndarray, d: np.ndarray, tg: BoxTarget) -> tuple[np.ndarray, np.ndarray]:
    n = d.shape[0]
    t_out = np.full(n, np.inf)
    n_out = np.zeros((n, 3))
    # Cull with the bounding sphere (half the space diagonal): a ray whose line passes farther
    # than that from the centre, or that points away from a sphere it is outside of, cannot hit.
    oc = tg.center - o
    r2 = 0.25 * float(tg.size @ tg.size)
    along = _rowdot(d, oc)
    oc2 = _rowdot(oc, oc)
    perp2 = oc2 - along * along
    inside_sphere = oc2 <= r2
    cand = np.flatnonzero((perp2 <= r2 * (1 + 1e-12)) & ((along > 0.0) | inside_sphere))
    if cand.size == 0:
        return t_out, n_out
    dc = d[cand]
    rot = tg.rotation  # local -> sensor; rows of rot.T are the box axes in the sensor frame
    o_l = (o - tg.center) @ rot  # (3,) = rot.T @ (o - c); (k, 3) with per-ray origins
    if o_l.ndim == 2:
        o_l = o_l[cand]
    d_l = dc @ rot  # (k, 3) = (rot.T @ d_i) for each row
    half = 0.5 * tg.size
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d_l
        t1 = (-half - o_l) * inv
        t2 = (half - o_l) * inv
    # A ray parallel to a slab: inside the slab for all t if |o| <= h, else never.
    parallel = d_l == 0.0
    inside_slab = np.abs(o_l) <= half
    lo = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
    hi = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
    ax_near = np.argmax(lo, axis=1)
    ax_far = np.argmin(hi, axis=1)
    rows = np.arange(cand.size)
    t_near = lo[rows, ax_near]
    t_far = hi[rows, ax_far]
    hit = t_near <= t_far
    from_outside = hit & (t_near > 0.0)
    from_inside = hit & ~from_outside & (t_far > 0.0)
    t_out[cand] = np.where(from_outside, t_near, np.where(from_inside, t_far, np.inf))
    axis = np.where(from_outside, ax_near, ax_far)
    # Outward face normal: against the ray on entry, along it on exit.
    sgn = np.sign(d_l[rows, axis])
    sgn = np.where(from_outside, -sgn, sgn)
    n_out[cand] = rot.T[axis] * sgn[:, None]
    return t_out, n_out


def _cast_sphere(
    o: np.ndarray, d: np.ndarray, tg: SphereTarget
) -> tuple[np.ndarray, np.ndarray]:
    oc = o - tg.center
    b = _rowdot(d, oc)  # half the linear coefficient (|d| = 1)
    c = _rowdot(oc, oc) - tg.radius**2
    disc = b * b - c
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    t_lo = -b - sq
    t_hi = -b + sq
    t = np.where(t_lo > 0.0, t_lo, np.where(t_hi > 0.0, t_hi, np.inf))
    t = np.where(ok, t, np.inf)
    ts = np.where(np.isfinite(t), t, 0.0)
    normal = (oc + ts[:, None] * d) / tg.radius
    return t, normal


def intersect_target(
    target: Target, directions: np.ndarray, origin: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of each ray on one target: (range_m (n,), surface normal (n, 3)); inf = miss.

    ``origin``: (3,), or (n, 3) for one origin per ray (a moving target cast at each ray's own time is
    the target at rest seen from a moved origin: sim_devices.world.motion).

    The normal's sign is not normalised (incidence uses |cos|). No argument checking: see cast().
    """
    if isinstance(target, PlaneTarget):
        return _cast_plane(origin, directions, target)
    if isinstance(target, PolygonTarget):
        return _cast_polygon(origin, directions, target)
    if isinstance(target, BoxTarget):
        return _cast_box(origin, directions, target)
    if isinstance(target, SphereTarget):
        return _cast_sphere(origin, directions, target)
    raise TypeError(f"unknown target type {type(target).__name__}")


# --------------------------------------------------------------------------------------------------
# Combination over targets
# --------------------------------------------------------------------------------------------------


def _check_args(
    directions: np.ndarray, max_hits: int, origin: np.ndarray | tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray, int]:
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise RayError(f"cast: directions must have shape (n, 3), got {d.shape}")
    if not np.all(np.isfinite(d)):
        bad = int(np.argwhere(~np.isfinite(d))[0, 0])
        raise RayError(f"cast: directions[{bad}] is not finite: {d[bad].tolist()}")
    norms = np.linalg.norm(d, axis=1)
    off = np.abs(norms - 1.0) > UNIT_TOL
    if np.any(off):
        bad = int(np.argmax(off))
        raise RayError(
            "cast: directions must be unit vectors; "
            f"directions[{bad}] has norm {float(norms[bad])!r}"
        )
    o = np.asarray(origin, dtype=np.float64)
    if o.shape not in ((3,), (d.shape[0], 3)) or not np.all(np.isfinite(o)):
        raise RayError("cast: origin must be 3 finite numbers (or one row of 3 per ray), "
                       f"got shape {o.shape}")
    if isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer)) or max_hits < 1:
        raise RayError(f"cast: max_hits must be an integer >= 1, got {max_hits!r}")
    return d, o, int(max_hits)


def cast(
    scene: _HasTargets,
    directions: np.ndarray,
    max_hits: int = 4,
    origin: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Hits:
    """Cast rays from ``origin`` ((3,), or (n, 3): one per ray, e.g. the footprint sub-rays that
    leave the lens off its centre) along unit ``directions`` (n, 3) into ``scene``.

    Returns :class:`Hits` with up to ``max_hits`` hits per ray, sorted by range, ties and
    transmission handled as described in the module docstring.
    """
    d, o, k = _check_args(directions, max_hits, origin)
    n, n_t = d.shape[0], len(scene.targets)

    width = max(n_t, k)
    # Targets as rows while filling (contiguous writes), transposed to rays x targets for sorting.
    t_all = np.full((width, n), np.inf)
    normal_all = np.zeros((width, n, 3))
    for j, tg in enumerate(scene.targets):
        t_all[j], normal_all[j] = intersect_target(tg, d, o)
    t_all = t_all.T
    pad = width - n_t  # padding columns never hit
    refl_t = np.array([tg.reflectivity for tg in scene.targets] + [0.0] * pad)
    trans_t = np.array([tg.transmission for tg in scene.targets] + [1.0] * pad)
    vel_t = np.array([tg.velocity for tg in scene.targets] + [np.zeros(3)] * pad).reshape(width, 3)

    order = np.argsort(t_all, axis=1, kind="stable")
    t_s = np.take_along_axis(t_all, order, axis=1)
    # Tie rule: chains of hits within TIE_TOL_M form a group ordered by target index. Only rows
    # that have such a chain are re-sorted (a stable argsort already orders exact ties by index,
    # but a near-tie may sort the later-listed target first).
    with np.errstate(invalid="ignore"):
        close = np.diff(t_s, axis=1) <= TIE_TOL_M  # inf - inf = nan -> False
    tie_rows = np.flatnonzero(close.any(axis=1))
    if tie_rows.size:
        o_t = order[tie_rows]
        group = np.concatenate(
            [np.zeros((tie_rows.size, 1), dtype=np.int64), np.cumsum(~close[tie_rows], axis=1)],
            axis=1,
        )
        o_t = np.take_along_axis(o_t, np.argsort(group * width + o_t, axis=1, kind="stable"), 1)
        order[tie_rows] = o_t
        t_s[tie_rows] = np.take_along_axis(t_all[tie_rows], o_t, axis=1)

    # Only the first k sorted hits can be returned, and their transmission depends only on the
    # hits in front of them.
    order, t_s = order[:, :k], t_s[:, :k]
    valid = np.isfinite(t_s)
    trans_s = np.where(valid, trans_t[order], 1.0)
    # One-way power reaching hit k: product of the transmissions of hits 0..k-1.
    reach = np.ones_like(trans_s)
    if k > 1:
        reach[:, 1:] = np.cumprod(trans_s[:, :-1], axis=1)
    valid &= reach > 0.0  # behind an opaque target
    # Misses and dropped hits sort to the end: valid hits form a prefix of each row.

    idx = np.where(valid, order, -1)
    range_m = np.where(valid, t_s, np.inf)
    normal_s = normal_all[order, np.arange(n)[:, None]]  # (n, k, 3)
    # atan2(|d x n|, |d . n|) stays accurate near normal incidence, where arccos(d . n) loses
    # half the digits (an error of 1e-12 in the cosine is 1.4e-6 rad).
    sin_s = np.linalg.norm(np.cross(normal_s, d[:, None, :]), axis=-1)
    cos_s = np.abs(np.einsum("nkj,nj->nk", normal_s, d))
    incidence = np.where(valid, np.arctan2(sin_s, cos_s), np.nan)
    refl = np.where(valid, refl_t[order], 0.0)
    radial = np.where(valid, np.einsum("nkj,nj->nk", vel_t[order], d), 0.0)
    transmission = np.where(valid, reach, 0.0)
    with np.errstate(invalid="ignore"):
        o_b = o if o.ndim == 1 else o[:, None, :]
        points = np.where(valid[..., None], o_b + range_m[..., None] * d[:, None, :], np.nan)
    return Hits(
        range_m=range_m,
        incidence_rad=incidence,
        reflectivity=refl,
        radial_velocity_mps=radial,
        transmission=transmission,
        target_index=idx.astype(np.int64),
        count=np.count_nonzero(valid, axis=1).astype(np.int64),
        points_m=points,
    )
