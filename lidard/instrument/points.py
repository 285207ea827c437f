"""DSP -> points: raw segment batches through the frame DSP into point records (dissertation §4.4.3).

The range, radial velocity and intensity of every detected return (§2.1.1-2.1.2: the beat frequencies
of the up and down ramps) come from :class:`lidard.dsp.frame.FrameDsp`; here they become points along
each pixel's beam direction (the FPSA optics of §4.3.4 map row/column to a direction).

The digitizer is read in short batches (the safety check wants short reads), but the DSP wants long
ones (its per-call set-up costs as much as many pixels), so :class:`PointBuffer` holds raw batches
until ``flush_bytes`` are together: memory stays bounded by one buffer, never a frame of raw samples.
With ``processes`` the batches go to the process's DSP worker processes (:class:`.pipeline.ProcessDspPipeline`,
:mod:`lidard.dsp_pool`), with ``workers`` (or when no pool is to be had) to DSP worker threads
(:class:`.pipeline.DspPipeline`); either is bounded and in order, and the reads go on meanwhile; the
points keep the pixel order and are the serial DSP's bit for bit. Every batch takes the one DSP path
the job decided before its first batch (:meth:`PointBuffer.set_path`, lidard.dsp.spectrum.jit.plan_path),
on whichever thread or worker process runs it.
"""

from __future__ import annotations

import dataclasses
from typing import Any
import logging
from dataclasses import dataclass

import numpy as np

from ..dsp.frame import FrameDsp
from ..dsp.spectrum.jit import DspPath, check_path, follow
from ..dsp.spectrum.scratch import release as release_scratch
from ..raw.points import frame_points
from .pipeline import DspPipeline, ProcessDspPipeline
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
                 zero_offset_m: float = 0.0, workers: int = 0, processes: bool = False):
        """``workers``: DSP threads (0: the DSP runs in :meth:`flush`, on the caller's thread);
        ``processes``: the process's DSP pool instead, when it has one free (else ``workers`` threads)."""
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
        self._pipe: DspPipeline | ProcessDspPipeline | None = None
        if processes:
            self._pipe = ProcessDspPipeline.open(dsp, lsb_v=lsb_v, mzi_delay_s=mzi_delay_s, finish=self._finish)
        if self._pipe is None and workers > 0:
            self._pipe = DspPipeline(self._process, workers)
        self.dsp_path: DspPath | None = None      # the job's (set_path); None: the process's rule
        self._started = False

    @property
    def pooled(self) -> bool:
        """Whether the batches go to the DSP pool's worker processes (they have the kernels loaded)."""
        return isinstance(self._pipe, ProcessDspPipeline)

    def set_path(self, path: str) -> None:
        """The DSP path every batch takes (lidard.dsp.spectrum.jit), set once it is known where the
        batches run and before the first one: a job never changes paths part-way."""
        if self._started:
            raise RuntimeError("PointBuffer.set_path: the DSP path is set before the first batch")
        self.dsp_path = check_path(path)
        if isinstance(self._pipe, ProcessDspPipeline):
            self._pipe.dsp_path = self.dsp_path

    def _collect(self, wait: bool = False) -> None:
        """Move the DSP workers' finished batches (in order) to the points; a worker's error is raised."""
        if self._pipe is not None:
            self._chunks.extend(self._pipe.ready(wait))

    def take_new(self) -> np.ndarray | None:
        """The points processed since the last call (for live viewers), or None when there are none."""
        self._collect()
        new = self._chunks[self._handed_over:]
        self._handed_over = len(self._chunks)
        return np.concatenate(new) if new else None

    @property
    def count(self) -> int:
        self._collect()
        return int(sum(len(c) for c in self._chunks))

    def add(self, batch: RawBatch, *, last: bool = False) -> None:
        self._collect()       # a DSP worker's error stops the scan here, as a synchronous DSP would
        self._pending.append(batch)
        self._pending_bytes += batch.nbytes
        if self._pending_bytes >= self.flush_bytes or last:
            self.flush()

    def flush(self) -> None:
        """The pending batches to the DSP: processed here, or queued for a worker (blocks while the
        workers' queue is full)."""
        if not self._pending:
            return
        pend, self._pending, self._pending_bytes = self._pending, [], 0
        self._started = True
        if isinstance(self._pipe, ProcessDspPipeline):     # joined straight into the worker's slot
            big = {f: [getattr(b, f) for b in pend] for f in ("beat", "mzi", "mzi_q", "beat_q")
                   if getattr(pend[0], f) is not None}
            meta = tuple(_joined(pend, f) for f in ("pixels", "t_pix_s", "clipped")) + (pend[0].beat.shape[1],)
            self._pipe.submit(big, meta)
            return
        job = RawBatch(*(_joined(pend, f.name) for f in dataclasses.fields(RawBatch)))
        del pend
        if self._pipe is None:
            self._chunks.append(self._process(job))
        else:
            self._pipe.submit(job)

    def _process(self, b: RawBatch) -> np.ndarray:
        """One batch through the frame DSP into point records (on whichever thread runs it)."""
        with follow(self.dsp_path):
            res = self.dsp.process(b.beat, self.lsb_v, mzi=b.mzi, mzi_delay_s=self.mzi_delay_s,
                                   mzi_lsb_v=self.lsb_v, mzi_q=b.mzi_q, beat_q=b.beat_q)
        return points_from(res, self.optics, b.pixels, b.t_pix_s, b.clipped, self.zero_offset_m,
                           delay_s=self.dsp.measurement_delay_s(b.beat.shape[1]))

    def _finish(self, res, meta: tuple) -> np.ndarray:
        """A worker process's frame result into point records (as :meth:`_process` does)."""
        pixels, t_pix, clipped, averages = meta
        return points_from(res, self.optics, pixels, t_pix, clipped, self.zero_offset_m,
                           delay_s=self.dsp.measurement_delay_s(averages))

    def drain(self) -> None:
        """Wait for the batches in the DSP workers (their points join; an error is raised)."""
        self._collect(wait=True)

    def points(self) -> np.ndarray:
        """Every point so far; a batch still waiting is processed first (a failure there is logged:
        the points before it are reported, the cause of the stop is already on its way)."""
        try:
            self.flush()
            if self._pipe is not None:
                while self._pipe.in_flight:
                    try:
                        self._collect(wait=True)
                    except Exception as exc:      # that batch's points are lost; the later ones are kept
                        log.warning("processing a batch failed: %s", exc)
        except Exception as exc:
            log.warning("processing the last batch failed: %s", exc)
        finally:
            self.close()
            release_scratch()     # the DSP's per-thread buffers (lidard.dsp.spectrum.scratch): an idle daemon holds none
        return np.concatenate(self._chunks) if self._chunks else np.zeros(0, POINT_DTYPE)

    def close(self) -> None:
        """End the DSP workers once their queued batches are done (they drop their scratch buffers);
        later batches are processed on the caller's thread. Safe to call again."""
        if self._pipe is not None:
            pipe, self._pipe = self._pipe, None
            pipe.close()
            while pipe.in_flight:
                try:
                    self._chunks.extend(pipe.ready(wait=True))
                except Exception as exc:    # the scan is ending on another error: report, do not mask it
                    log.warning("processing a batch failed: %s", exc)


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


def _joined(batches: list[RawBatch], name: str) -> Any:
    """One field over consecutive batches (None stays None)."""
    return None if getattr(batches[0], name) is None else np.concatenate([getattr(b, name) for b in batches])
