"""A raw replay's task that also hands back the frame DSP's float64 results behind its points.

The points are float32, so a DSP difference at rounding level (~1e-15 relative) shows in them only now
and then (a last bit on 2 of 1,744 points of a 10 m/s region replay); the float64 values behind them
show every such difference. A module of its own, importable by name: a process pool's or the DSP
pool's workers unpickle :func:`task_points_and_results` by reference.
"""

from __future__ import annotations

import numpy as np

from lidard.raw import replay

RESULT_FIELDS = ("range_m", "velocity_mps", "intensity_v", "snr_db")


def task_points_and_results(raw_path: str, task_index: int, chunks_per_task: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`lidard.raw.replay.reprocess_task`'s points, and the FrameResult its points were made from
    (its :data:`RESULT_FIELDS` stacked: (4, pixels, slots) float64)."""
    seen = []
    real = replay.frame_points

    def spy(res, *args, **kw):
        seen.append(res)
        return real(res, *args, **kw)

    replay.frame_points = spy       # this worker's module only, put back below
    try:
        pts = replay.reprocess_task(raw_path, task_index, None, chunks_per_task)
    finally:
        replay.frame_points = real
    (res,) = seen
    return pts, np.stack([getattr(res, f) for f in RESULT_FIELDS])
