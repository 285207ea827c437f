"""DSP -> points: raw segment batches through the frame DSP into point records (dissertation §4.4.3).

The range, radial velocity and intensity of every detected return (§2.1.1-2.1.2: the beat frequencies
of the up and down ramps) come from :class:`lidard.dsp.frame.FrameDsp`; here they become points along
each pixel's beam direction (the FPSA optics of §4.3.4 map row/column to a direction).

The digitizer is read in short batches (the safety check wants short reads), but the DSP wants long
ones (its per-call set-up costs as much as many pixels), so :class:`PointBuffer` holds raw batches
until ``flush_bytes`` are together: memory stays bounded by one buffer, never a frame of raw samples.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from ..dsp.frame import FrameDsp
from ..dsp.scratch import release as release_scratch
from ..raw.points import frame_points
from .types import POINT_DTYPE

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RawBatch:
    """Consecutive pixels' segments as read: ``beat``/``mzi``/``mzi_q`` are (pixels, averages, samples)."""

    beat: np.ndarray
    pixels: np.ndarray               # (pixels, 2) row, col
    t_pix_s: np.ndarray              # hardware time of each pixel's first trigger since scan start
    clipped: np.ndarray              # a segment of the pixel was over range
    mzi: np.ndarray | None = None    # monitor MZI records (phase-noise compensation, §2.3)
    mzi_q: np.ndarray | None = None  # the monitor's quadrature output (compensation at any range)
    beat_q: np.ndarray | None = None  # the I/Q receiver's Q channel (``beat`` is then I)

    @property
    def nbytes(self) -> int:
        return self.beat.nbytes * (1 + (self.mzi is not None) + (self.mzi_q is not None) + (self.beat_q is not None))


class PointBuffer:
    """Collects raw batches, runs the DSP once ``flush_bytes`` are together, keeps the points."""

    def __init__(self, dsp: FrameDsp, optics, *, lsb_v: float, mzi_delay_s: float, flush_bytes: int,
                 zero_offset_m: float = 0.0):
        self.dsp = dsp
        self.zero_offset_m = zero_offset_m
        self.optics = optics
        self.lsb_v = lsb_v
        self.mzi_delay_s = mzi_delay_s
        self.flush_bytes = flush_bytes
        self._pending: list[RawBatch] = []
        self._pending_bytes = 0
        self._chunks: list[np.ndarray] = []
        self._handed_over = 0

    def take_new(self) -> np.ndarray | None:
        """The points processed since the last call (for live viewers), or None when there are none."""
        new = self._chunks[self._handed_over:]
        self._handed_over = len(self._chunks)
        return np.concatenate(new) if new else None

    @property
    def count(self) -> int:
        return int(sum(len(c) for c in self._chunks))

    def add(self, batch: RawBatch, *, last: bool = False) -> None:
        self._pending.append(batch)
        self._pending_bytes += batch.nbytes
        if self._pending_bytes >= self.flush_bytes or last:
            self.flush()

    def flush(self) -> None:
        if not self._pending:
            return
        pend, self._pending, self._pending_bytes = self._pending, [], 0
        beat = np.concatenate([p.beat for p in pend])
        mzi = np.concatenate([p.mzi for p in pend]) if pend[0].mzi is not None else None
        mzi_q = np.concatenate([p.mzi_q for p in pend]) if pend[0].mzi_q is not None else None
        beat_q = np.concatenate([p.beat_q for p in pend]) if pend[0].beat_q is not None else None
        res = self.dsp.process(beat, self.lsb_v, mzi=mzi, mzi_delay_s=self.mzi_delay_s, mzi_lsb_v=self.lsb_v,
                               mzi_q=mzi_q, beat_q=beat_q)
        self._chunks.append(points_from(res, self.optics, np.concatenate([p.pixels for p in pend]),
                                        np.concatenate([p.t_pix_s for p in pend]),
                                        np.concatenate([p.clipped for p in pend]), self.zero_offset_m,
                                        delay_s=self.dsp.measurement_delay_s(beat.shape[1])))

    def points(self) -> np.ndarray:
        """Every point so far; a batch still waiting is processed first (a failure there is logged:
        the points before it are reported, the cause of the stop is already on its way)."""
        try:
            self.flush()
        except Exception as exc:
            log.warning("processing the last batch failed: %s", exc)
        finally:
            release_scratch()     # the DSP's per-thread buffers (lidard.dsp.scratch): an idle daemon holds none
        return np.concatenate(self._chunks) if self._chunks else np.zeros(0, POINT_DTYPE)


def points_from(res, optics, px: np.ndarray, t_pix: np.ndarray, clipped: np.ndarray | None = None,
                zero_offset_m: float = 0.0, delay_s: float = 0.0) -> np.ndarray:
    """Point records for every present return of a frame result (``res.present[pixel, k]``), along
    each pixel's beam direction. The record building itself is :func:`lidard.raw.points.frame_points`,
    shared with the replay of raw captures so that a replay gives these points bit for bit.

    ``zero_offset_m``: the range calibration's zero offset (the path from the reference reflection to
    the lens every beat carries), taken off the range before x, y, z are placed along the ray;
    ``delay_s``: ranges moved back to each point's ``t`` (:func:`lidard.raw.points.frame_points`)."""
    if zero_offset_m:
        res = dataclasses.replace(res, range_m=res.range_m - zero_offset_m)
    return frame_points(res, px, t_pix, optics.directions(px[:, 0], px[:, 1]), clipped, delay_s)
