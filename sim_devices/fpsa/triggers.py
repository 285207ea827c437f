"""The seam between the simulated FPGA and the digitizer/AWG on the bench: trigger schedules.

The FPGA steps a scan pattern on its own clock (§4.3.3, Fig. 4-22): for each pixel it loads the
row and column into the HV583s (0.8 us: 32 bits per register at 40 MHz), latches, waits for the
MEMS switches to settle (§4.3.6), emits ``triggers_per_pixel`` hardware triggers
``trigger_period`` apart (each starts one chirp on the AWG and one digitizer segment), then dwells
and moves on. :class:`PixelSchedule` is that timing in closed form; :class:`TriggerBatch` is what
the bench gets back for a range of triggers: when each fired, which pixel was commanded, and which
beams actually left the chip during the capture window (more than one during a switch transition).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TriggerBatch:
    """Triggers ``index[0] .. index[-1]`` of a run and the beams each capture window sees.

    Per trigger: ``index`` (int64, global counter within the run), ``t_s`` (float64 trigger time
    on the virtual clock), ``pixel_index`` (int32 into the pattern), ``row``/``col`` (int16, the
    commanded pixel). Per lit beam (flat, any number per trigger, including zero or several):
    ``beam_trigger`` (int32 index into this batch), ``beam_row``/``beam_col`` (int16) and
    ``beam_transmission`` (float64, T_row * T_col averaged over [t_s, t_s + capture_s]).
    """

    index: np.ndarray
    t_s: np.ndarray
    pixel_index: np.ndarray
    row: np.ndarray
    col: np.ndarray
    beam_trigger: np.ndarray
    beam_row: np.ndarray
    beam_col: np.ndarray
    beam_transmission: np.ndarray
    capture_s: float = 0.0

    def __post_init__(self) -> None:
        n = self.index.shape[0]
        for name in ("t_s", "pixel_index", "row", "col"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"TriggerBatch.{name} must have shape ({n},)")
        m = self.beam_trigger.shape[0]
        for name in ("beam_row", "beam_col", "beam_transmission"):
            if getattr(self, name).shape != (m,):
                raise ValueError(f"TriggerBatch.{name} must have shape ({m},)")

    def __len__(self) -> int:
        return int(self.index.shape[0])

    def beams_of(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, transmissions) of the beams lit for trigger ``i`` of this batch."""
        m = self.beam_trigger == i
        return self.beam_row[m], self.beam_col[m], self.beam_transmission[m]

    def window(self, a: int, b: int) -> TriggerBatch:
        """Triggers ``a .. b-1`` of this batch (positions in it) with their beams, re-indexed to the
        new batch (copies: the batch may be kept and sliced again). The beams are in trigger order."""
        lo, hi = (int(x) for x in np.searchsorted(self.beam_trigger, [a, b]))
        return TriggerBatch(
            index=self.index[a:b].copy(), t_s=self.t_s[a:b].copy(), pixel_index=self.pixel_index[a:b].copy(),
            row=self.row[a:b].copy(), col=self.col[a:b].copy(),
            beam_trigger=(self.beam_trigger[lo:hi] - a).astype(self.beam_trigger.dtype),
            beam_row=self.beam_row[lo:hi].copy(), beam_col=self.beam_col[lo:hi].copy(),
            beam_transmission=self.beam_transmission[lo:hi].copy(), capture_s=self.capture_s)

    @classmethod
    def empty(cls, capture_s: float = 0.0) -> TriggerBatch:
        z = np.zeros(0)
        return cls(z.astype(np.int64), z.astype(np.float64), z.astype(np.int32),
                   z.astype(np.int16), z.astype(np.int16), z.astype(np.int32),
                   z.astype(np.int16), z.astype(np.int16), z.astype(np.float64), capture_s)


@dataclass(frozen=True)
class PixelSchedule:
    """Closed-form timing of one run of ``n_pixels`` (see docs/protocols/fpsa.md, "timing").

    ``cut_s`` is when the run stopped (STOP/RESET) or ``inf``; nothing happens at or after it.
    """

    run_start_s: float
    n_pixels: int
    refresh_s: float
    settle_s: float
    trigger_period_s: float
    triggers_per_pixel: int
    dwell_s: float
    cut_s: float = math.inf

    @property
    def pixel_period_s(self) -> float:
        return (self.refresh_s + self.settle_s + self.triggers_per_pixel * self.trigger_period_s
                + self.dwell_s)

    @property
    def natural_end_s(self) -> float:
        return self.run_start_s + self.n_pixels * self.pixel_period_s

    @property
    def end_s(self) -> float:
        return min(self.natural_end_s, self.cut_s)

    def latch_s(self, pixel: np.ndarray) -> np.ndarray:
        return self.run_start_s + np.asarray(pixel, np.float64) * self.pixel_period_s + self.refresh_s

    def trigger_s(self, index: np.ndarray) -> np.ndarray:
        index = np.asarray(index, np.int64)
        pixel, k = np.divmod(index, self.triggers_per_pixel)
        return self.latch_s(pixel) + self.settle_s + k * self.trigger_period_s

    def triggers_before(self, t_s: float) -> int:
        """Number of triggers fired at or before ``t_s`` (and before the cut)."""
        t = min(t_s, float(np.nextafter(self.cut_s, -math.inf)), self.natural_end_s)
        rel = t - self.run_start_s
        if rel < 0:
            return 0
        m = self.triggers_per_pixel
        full = min(int(rel // self.pixel_period_s), self.n_pixels)
        if full >= self.n_pixels:
            return self.n_pixels * m
        in_pixel = rel - full * self.pixel_period_s - self.refresh_s - self.settle_s
        k = 0 if in_pixel < 0 else min(int(in_pixel // self.trigger_period_s) + 1, m)
        return full * m + k

    @property
    def total_triggers(self) -> int:
        return self.triggers_before(math.inf)

    def pixels_done(self, t_s: float) -> int:
        """Pixels whose last trigger has fired by ``t_s``."""
        return self.triggers_before(t_s) // self.triggers_per_pixel

    def pattern_index(self, t_s: float) -> int:
        """Index of the pixel being shown (or loaded) at ``t_s``, clipped to the pattern."""
        rel = min(t_s, self.end_s) - self.run_start_s
        if rel <= 0:
            return 0
        return min(int(rel // self.pixel_period_s), self.n_pixels - 1)
