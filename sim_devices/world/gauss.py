"""White Gaussian noise for the digitizer records, float32, by the Box-Muller transform.

The additive noise of every record (shot + RIN + thermal + ambient, dissertation §2.4 eqs.
2-16..2-21, drawn in :mod:`sim_devices.world.synth`) is the largest single cost of a frame's
synthesis: numpy's ziggurat ``Generator.standard_normal(dtype=float32)`` costs ~8 ns a sample here
(its per-sample branch and table look-ups do not vectorize), where the Box-Muller transform, two
uniform draws and a log, a sqrt, a cos and a sin per PAIR of samples, all SIMD loops, costs about a
third of that (benchmarks/noise.py prints both).

Exact Gaussian: for independent U1 in (0, 1] and U2 in [0, 1), R = sqrt(-2 ln U1) and
Theta = 2 pi U2 give two independent standard normals R cos Theta and R sin Theta. The radius is
computed in float64 from 53-bit uniforms (largest radius sqrt(2 ln 2^53) = 8.6 sigma, so the tails
are not cut where any test or CFAR threshold looks); the angle needs only float32 (24 bits of angle
move a sample by < 4e-7 sigma). The stream differs from ``standard_normal``'s; it is reproducible
for the same generator state.
"""

from __future__ import annotations

import numpy as np

_TWO_PI_F32 = np.float32(2.0 * np.pi)


def standard_normal_f32(rng: np.random.Generator, shape, scale: float = 1.0) -> np.ndarray:
    """Independent normal samples of ``shape``, float32, of standard deviation ``scale`` (module
    docstring; the scale multiplies the float64 radius, so it costs no pass over the samples)."""
    out = np.empty(shape, dtype=np.float32)
    flat = out.reshape(-1)
    n = flat.size
    half = (n + 1) // 2
    radius = rng.random(half)                    # [0, 1): 1 - U is in (0, 1]
    np.subtract(1.0, radius, out=radius)
    np.log(radius, out=radius)
    radius *= -2.0 * float(scale) ** 2
    np.sqrt(radius, out=radius)
    r32 = radius.astype(np.float32)
    del radius
    angle = rng.random(half, dtype=np.float32)
    angle *= _TWO_PI_F32
    np.cos(angle, out=flat[:half])
    flat[:half] *= r32
    rest = n - half                              # n odd: the last pair's sine is not needed
    if rest:
        np.sin(angle[:rest], out=flat[half:])
        flat[half:] *= r32[:rest]
    return out
