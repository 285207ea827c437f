"""From the frame DSP's per-pixel results to point records: one function for the scan and for replay.

The scan loop (dissertation §4.4.1: the FPGA steps the pattern, the host turns each batch of
segments into points) and :mod:`lidard.raw.replay` both call :func:`frame_points`, so a replay
of a raw capture with the original settings yields the original points bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..dsp.frame import FrameResult
from ..dsp.detect.gate import PointFlag
from ..outputs.schema import POINT_DTYPE


def frame_points(res: FrameResult, pixels: np.ndarray, t_s: np.ndarray, directions: np.ndarray,
                 clipped: np.ndarray | None = None, delay_s: float = 0.0) -> np.ndarray:
    """Point records (POINT_DTYPE) for every present return of a batch.

    ``pixels`` (n_pix, 2) rows/cols of the batch in scan order, ``t_s`` (n_pix,) their times,
    ``directions`` (n_pix, 3) their unit beam directions (x, y, z = direction * range),
    ``clipped`` (n_pix,) pixels with an overranged record: their points are never valid.
    ``delay_s``: from ``t`` to the instant the DSP's ranges refer to
    (:meth:`lidard.dsp.frame.FrameDsp.measurement_delay_s`): each range is moved back to its point's
    ``t`` with its own radial velocity, R(t) = R - v delay_s.
    Order: by pixel, then by the DSP's return slot; ``return_index`` counts returns along one beam
    by range (0 = nearest).
    """
    if clipped is not None:     # a clipped record's spectrum has harmonics
        res = res.refused(np.asarray(clipped, dtype=bool)[:, None], PointFlag.CLIPPED)
    pi, ki = np.nonzero(res.present)
    out = np.zeros(len(pi), POINT_DTYPE)
    if not len(pi):
        return out
    rng_m = res.range_m[pi, ki]
    if delay_s:
        rng_m = rng_m - res.velocity_mps[pi, ki] * delay_s
    xyz = np.asarray(directions, dtype=np.float64)[pi] * rng_m[:, None]
    out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    out["range"] = rng_m
    out["velocity"] = res.velocity_mps[pi, ki]
    out["intensity"] = res.intensity_v[pi, ki]
    out["snr_db"] = res.snr_db[pi, ki]
    out["row"], out["col"] = pixels[pi, 0], pixels[pi, 1]
    order = np.lexsort((rng_m, pi))
    same = np.r_[False, pi[order][1:] == pi[order][:-1]]
    run = np.cumsum(~same) - 1
    starts = np.flatnonzero(~same)
    ri = np.zeros(len(pi), np.int64)
    ri[order] = np.arange(len(pi)) - starts[run]
    out["return_index"] = ri
    out["t"] = np.asarray(t_s, dtype=np.float64)[pi]
    out["valid"] = res.valid[pi, ki]
    if res.flags is not None:
        out["flags"] = res.flags[pi, ki]
    return out
