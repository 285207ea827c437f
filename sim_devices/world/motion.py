"""Targets that move during a scan: each beam sees the scene at its own hardware time.

The scene file gives every target's position at scene time t = 0, the first trigger of the run (the
scan's first measured pixel; a point's ``t`` counts from the same trigger), and a constant velocity.
A beam fired at time t sees a moving target translated by v t. Only the moving targets need casting
at each beam's time: the static ones keep the World's per-pixel cache (cast once per pixel), and
the moving ones are cast per beam, vectorized over beams, as the target at rest seen from the origin
moved by -v t (raycast.intersect_target takes one origin per ray). The two hit lists of a beam are
then merged the way raycast.cast orders one scene: by range, each hit's one-way transmission the
product of the transmissions of the hits in front, nothing behind an opaque hit, at most
``max_hits``. The beat synthesis adds the within-chirp range drift (the Doppler term, §2.1.2).

Moving targets are cast with one ray per pixel (no footprint sub-rays: a mixed pixel of a moving
edge is not modelled); static targets keep theirs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .raycast import intersect_target
from .scene import Scene


@dataclass(frozen=True)
class SceneMotion:
    """A scene split into its static part (cached per pixel) and its moving targets."""

    static: Scene                     # the static targets only (the scene itself when none move)
    static_index: np.ndarray          # index in the full scene of each static target
    moving_index: np.ndarray          # indices in the full scene of the moving targets
    transmission: np.ndarray          # every target's one-way transmission (full-scene order)

    @classmethod
    def of(cls, scene: Scene) -> SceneMotion:
        moving = np.array([bool(np.any(t.velocity != 0)) for t in scene.targets], bool)
        trans = np.array([float(t.transmission) for t in scene.targets])
        if not moving.any():
            return cls(scene, np.arange(len(scene.targets)), np.zeros(0, np.int64), trans)
        keep = tuple(t for t, m in zip(scene.targets, moving) if not m)
        static = Scene(keep, scene.name, scene.description, scene.source, scene.mixed_pixels)
        return cls(static, np.flatnonzero(~moving), np.flatnonzero(moving), trans)

    @property
    def any_moving(self) -> bool:
        return self.moving_index.size > 0


def cast_moving(scene: Scene, motion: SceneMotion, d: np.ndarray, t_s: np.ndarray) -> tuple:
    """Hits of the moving targets on rays ``d`` (n, 3) fired at scene times ``t_s`` (n,): flat arrays
    (ray, range, incidence, reflectivity, radial velocity, target) over every (ray, moving target) hit."""
    out = []
    for j in motion.moving_index:
        tg = scene.targets[int(j)]
        rng, normal = intersect_target(tg, d, -np.outer(t_s, tg.velocity))
        ray = np.flatnonzero(np.isfinite(rng))
        if ray.size == 0:
            continue
        dd, nn = d[ray], np.asarray(normal)[ray]
        sin = np.linalg.norm(np.cross(nn, dd), axis=-1)
        cos = np.abs(np.einsum("nj,nj->n", nn, dd))
        out.append((ray, rng[ray], np.arctan2(sin, cos), np.full(ray.size, float(tg.reflectivity)),
                    dd @ tg.velocity, np.full(ray.size, float(j))))
    if not out:
        z = np.zeros(0)
        return (np.zeros(0, np.int64), z, z, z, z, z)
    return tuple(np.concatenate(c) for c in zip(*out))


def merge(static: list[np.ndarray], beam: np.ndarray, moving: tuple, transmission: np.ndarray,
          max_hits: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Static hits (the 7 flat arrays of World.beam_hits: range, incidence, albedo, radial velocity,
    transmission chain, target, weight; ``beam`` their beam index) merged with the moving hits of
    :func:`cast_moving`: (the 7 arrays, beam) sorted by beam then range."""
    ray, rng, inc, rho, vel, tgt = moving
    if ray.size == 0:
        return static, beam
    has = np.zeros(int(max(beam.max(initial=-1), ray.max())) + 1, bool)
    has[ray] = True
    touched = has[beam]                         # static hits of beams a moving target reaches
    cols = [np.concatenate([a[touched], m]) for a, m in
            zip(static, (rng, inc, rho, vel, np.ones(ray.size), tgt, np.ones(ray.size)))]
    b = np.concatenate([beam[touched], ray])
    order = np.lexsort((cols[0], b))
    cols, b = [c[order] for c in cols], b[order]
    start = np.r_[True, b[1:] != b[:-1]]
    first = np.flatnonzero(start)
    group = np.cumsum(start) - 1
    rank = np.arange(b.size) - first[group]
    own = transmission[cols[5].astype(np.int64)]
    # one-way power reaching each hit: product of the transmissions in front (an opaque one: none)
    opaque = np.cumsum(own == 0.0)
    with np.errstate(divide="ignore"):
        logs = np.cumsum(np.where(own > 0.0, np.log(np.where(own > 0.0, own, 1.0)), 0.0))

    def before(c):          # exclusive running sum within each beam's group
        return np.r_[0.0, c[:-1]] - np.r_[0.0, c][first[group]]

    chain = np.where(before(opaque) > 0, 0.0, np.exp(before(logs)))
    keep = (chain > 0.0) & (rank < max_hits)
    cols[4] = chain
    cols = [c[keep] for c in cols]
    merged = [np.concatenate([a[~touched], m]) for a, m in zip(static, cols)]
    mb = np.concatenate([beam[~touched], b[keep]])
    order = np.lexsort((merged[0], mb))
    return [m[order] for m in merged], mb[order]
