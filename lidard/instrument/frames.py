"""The data of a stream: what a planner asks of the next frame, a finished frame, a stream's result.

Kept apart from the frame loop (:mod:`.stream`) so that the planners (:mod:`lidard.instrument.tracking`, pure
functions of the last frames), the :class:`~lidard.instrument.protocol.Instrument` protocol and the
job layer use these types without importing the acquisition and DSP machinery.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Frame", "FramePlan", "Planner", "StreamResult", "pixel_period_s"]


@dataclass(frozen=True)
class FramePlan:
    """What the next frame visits, and the planner's account of the trade (the sidecar's ``plan``)."""

    pixels: np.ndarray
    trade: dict[str, Any] = field(default_factory=dict)


#: planner(frame_index, history) -> FramePlan; history: the finished frames, oldest first
Planner = Callable[[int, list], FramePlan]


@dataclass
class Frame:
    """One finished (or partial) frame of a stream."""

    index: int
    points: np.ndarray
    pixels: np.ndarray                 # (n, 2) the pixels planned for this frame
    pixels_scanned: int
    start_s: float                     # first trigger, since the stream's first trigger
    hardware_time_s: float             # first trigger to the end of the last record read
    setup_s: float                     # hardware gap before the first trigger since the last frame's end
    pixel_period_s: float              # hardware time one pixel takes (triggers + settle)
    partial: bool = False
    stop_reason: str | None = None
    trade: dict[str, Any] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)

    @property
    def coverage(self) -> float:
        return 0.0 if len(self.pixels) == 0 else self.pixels_scanned / len(self.pixels)

    def sidecar(self) -> dict[str, Any]:
        return {"frame": self.index, "start_s": self.start_s, "hardware_time_s": self.hardware_time_s,
                "setup_s": self.setup_s, "pixels_planned": len(self.pixels),
                "pixels_scanned": int(self.pixels_scanned), "coverage": self.coverage,
                "points": len(self.points), "valid_points": int(np.sum(self.points["valid"] == 1)),
                "partial": self.partial, "stop_reason": self.stop_reason, "plan": self.trade,
                "faults": dict(self.faults)}


@dataclass
class StreamResult:
    frames: int
    hardware_time_s: float
    stop_reason: str | None
    cancelled: bool
    health: list[dict[str, Any]]
    meta: dict[str, Any]


def pixel_period_s(cfg: Any, averages: int) -> float:
    """Hardware time one pixel takes: ``averages`` chirp periods after the switches' settle time
    (``cfg`` a :class:`lidard.config.Config`); the unit of a frame's pixel budget."""
    return int(averages) * cfg.chirp.period_s + cfg.scan.settle_s
