"""Fully developed speckle on returns from rough surfaces (a scene's ``speckle = true`` targets).

A surface rough on the scale of the wavelength, lit by a coherent beam, returns the sum of many
independent scatterers inside the footprint: by the central limit theorem the field is a circular
complex Gaussian, so the beat AMPLITUDE is Rayleigh distributed and its PHASE uniform on [0, 2 pi)
(Goodman, "Speckle phenomena in optics", ch. 3). The dissertation's link budget (§2.4, eq. 2-10)
gives the MEAN return power; speckle multiplies the beat amplitude by ``a`` with a^2 ~ Exp(1) (mean
power kept: E[a^2] = 1) and replaces the beat phase by a uniform one.

Correlation (what decides whether averaging helps):
* pixels: each pixel's footprint covers other scatterers: independent draws per (pixel, target);
* chirps: a static surface shows the SAME speckle in every chirp (averaging chirps cannot remove
  the fading, as on a real static wall); a surface with a non-zero velocity is assumed to move
  by more than a speckle correlation length per chirp period, so every chirp draws anew and
  averaging N chirps' powers reduces the fading variance as 1/N.

Draws are a counter-based hash (splitmix64) of (seed, pixel, target, chirp): the same bench seed
gives the same speckle whatever order or batch the pixels are captured in.
"""

from __future__ import annotations

import numpy as np

__all__ = ["speckle_factors"]

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _uniform(key: np.ndarray) -> np.ndarray:
    """(0, 1) doubles from 53 bits of a hash (never exactly 0: the log below stays finite)."""
    return ((_splitmix64(key) >> np.uint64(11)).astype(np.float64) + 0.5) / float(1 << 53)


def speckle_factors(seed: int, row: np.ndarray, col: np.ndarray, target: np.ndarray,
                    chirp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(amplitude factor, phase rad) per hit: Rayleigh with E[a^2] = 1, phase uniform in [0, 2 pi).

    ``chirp`` is the chirp (trigger) index for moving surfaces and 0 for static ones.
    """
    with np.errstate(over="ignore"):
        key: np.ndarray = np.asarray(np.uint64(seed & 0xFFFFFFFFFFFFFFFF))
        for part, bits in ((row, 12), (col, 12), (target, 16), (chirp, 40)):
            key = _splitmix64(key ^ (np.asarray(part).astype(np.uint64) & np.uint64((1 << bits) - 1)))
        key = np.asarray(key, np.uint64)
        u1 = _uniform(key)
        u2 = _uniform(key ^ np.uint64(0xD1B54A32D192ED03))
    return np.sqrt(-np.log(u1)), 2.0 * np.pi * u2
