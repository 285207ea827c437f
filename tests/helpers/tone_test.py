"""How many points of one scan the single-tone (model-order) test may draw instead of keeping.

The ranging DSP tests each ramp detection against the fitted tones at ``FrameDsp.order_level``: the
probability of rejecting a lone tone in noise (lidard.dsp.ranging.ramp). A point of a single surface
is flagged UNRESOLVED (drawn, not valid, never misranged) when its up- or its down-ramp detection is
rejected, so p <= 2 order_level per point. A test that asks "every pixel ranged" of one noise draw
holds a probability, not a certainty: it allows that many drawn pixels (binomial tail ``tail``), for
that reason only, and every other pixel must give a valid point.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.stats import binom

from lidard.dsp.frame import FrameDsp
from lidard.dsp.detect.gate import PointFlag

ORDER_LEVEL = next(f.default for f in dataclasses.fields(FrameDsp) if f.name == "order_level")


def tone_test_drawn_max(n_points: int, tail: float = 1e-4) -> int:
    """The most points of ``n_points`` single-surface points the single-tone test draws, but with
    probability ``tail``."""
    return int(binom.isf(tail, int(n_points), 2 * ORDER_LEVEL))


def assert_every_pixel_ranged(res, tail: float = 1e-4) -> np.ndarray:
    """Every scanned pixel gives one valid point, but for at most :func:`tone_test_drawn_max` pixels
    whose point the single-tone test drew (flagged UNRESOLVED and nothing else). Answers the valid
    points."""
    pts = res.points
    ok = pts["valid"] == 1
    key = pts["row"].astype(np.int64) * 65536 + pts["col"]
    assert len(np.unique(key[ok])) == int(ok.sum())                 # one valid point per pixel
    missing = res.pixels_scanned - int(ok.sum())
    drawn = ~ok & ~np.isin(key, key[ok])
    assert np.all(pts["flags"][drawn] == PointFlag.UNRESOLVED), pts[drawn]
    assert len(np.unique(key[drawn])) == missing, (missing, pts[drawn])    # a drawn point for each
    assert missing <= tone_test_drawn_max(res.pixels_scanned, tail), pts[drawn]
    return pts[ok]
