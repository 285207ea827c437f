"""Recording a scan's raw segments as it runs: the scan loop's side of a raw capture.

:class:`ScanRecorder` is created when an acquisition is ready (the digitizer has told its channel
order), fed every batch of segments the scan loop accepts (the same records its DSP gets; a batch
discarded after a safety stop is not recorded either) and closed with the scan's outcome. It
writes what :mod:`lidard.raw.replay` needs to run the same DSP again: the frame DSP's settings,
the ADC scale, the phase-noise choice and monitor delay (§2.3), the chirp and the calibration id
(§2.2), the pixel order and each beam's direction (§4.3.4 optics), the hardware time stamps.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from collections.abc import Sequence

import numpy as np

from drivers.digitizer.protocol_headers import header_column

from ..dsp.frame import FrameDsp
from .capture import RawWriter, chunk_pixels_for
from .replay import DSP_PATH_ATTR, frame_dsp_attrs

# Raw bytes per chunk (one reprocessing task): 1 MiB keeps a few thousand pixels in several tasks
# for a pool or a cluster and is still a comfortable size for the store (one file per chunk). The
# scan's DSP batches are larger (BATCH_BYTES, 8 MiB); the DSP treats pixels independently, so the
# two need not coincide. Tests lower it to get several chunks from a small scan.
RAW_CHUNK_BYTES = 1 << 20

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordLayout:
    """What the capture holds per pixel: the planned ``pixels`` (n, 2) in scan order, each beam's
    ``directions`` (n, 3), ``averages`` segments per pixel of ``record_length`` samples in each of
    ``channels`` (the digitizer's order: how records arrive)."""

    pixels: np.ndarray
    directions: np.ndarray
    averages: int
    channels: tuple[str, ...]
    record_length: int


@dataclass(frozen=True)
class ReplayRecipe:
    """What :mod:`lidard.raw.replay` needs to run the same DSP again: the frame DSP, the ADC's volts
    per code, the phase-noise choice, the monitor's delay (§2.3) and the DSP path the scan's points
    were computed on (lidard.dsp.spectrum.jit; None: not known, the replay decides as for an older capture)."""

    dsp: FrameDsp
    lsb_v: float
    phase_noise: bool
    mzi_delay_s: float
    dsp_path: str | None = None


@dataclass(frozen=True)
class ScanDescription:
    """JSON-ready descriptions stored as attributes: the ADC, the chirp, the calibration in use and
    the scan request."""

    adc: dict[str, Any]
    chirp: dict[str, Any]
    calibration_id: Any
    scan: dict[str, Any] = field(default_factory=dict)


class ScanRecorder:
    """Writes one scan's raw capture; every call is safe to make after a failure of the writer
    (a recording problem is logged and stops the recording, never the scan)."""

    def __init__(self, writer: RawWriter | None, channels: tuple[str, ...]):
        self.writer = writer
        self.channels = channels
        self.error: str | None = None
        self.pixels_recorded = 0        # pixels handed to the writer (committed or waiting for their chunk)

    @classmethod
    def start(cls, path: str | Path, layout: RecordLayout, recipe: ReplayRecipe, about: ScanDescription, *,
              drive_v: np.ndarray | None = None, chunk_bytes: int | None = None) -> ScanRecorder:
        """A new capture at ``path`` laid out as ``layout``, with what replays it (``recipe``) and what
        describes it (``about``) stored as attributes; ``drive_v``: the chirp's drive waveform."""
        ch = tuple(layout.channels)
        averages, record_length = int(layout.averages), int(layout.record_length)
        bytes_per_pixel = averages * record_length * 2 * len(ch)
        attrs = {
            "adc": {**about.adc, "lsb_v": float(recipe.lsb_v)},
            "dsp": frame_dsp_attrs(recipe.dsp),
            "phase_noise": {"on": bool(recipe.phase_noise), "mzi_delay_s": float(recipe.mzi_delay_s)},
            **({} if recipe.dsp_path is None else {DSP_PATH_ATTR: recipe.dsp_path}),
            "chirp": about.chirp,
            "calibration_id": about.calibration_id,
            "scan": about.scan or {},
            "pixel_order": "pixels[i] is the i-th pixel scanned; segment i * averages + k is its k-th chirp",
            "time_base": "t_s: the points' t (s since the scan's first trigger, continued across resumes); "
                         "trigger_time_ns: the digitizer's own time stamps",
        }
        writer = RawWriter.create(path, pixels=layout.pixels, directions=layout.directions, averages=averages,
                                  channels=ch, record_length=record_length,
                                  chunk_pixels=chunk_pixels_for(bytes_per_pixel, chunk_bytes or RAW_CHUNK_BYTES),
                                  attrs=attrs, drive_v=drive_v)
        return cls(writer, ch)

    def add(self, samples: np.ndarray, headers: Sequence[Any], t_pix_s: np.ndarray,
            channel_order: Sequence[str]) -> None:
        """One accepted batch: ``samples`` (segments, channels, record) in ``channel_order`` as read,
        the segment ``headers`` (``trigger_time_ns``, ``overrange``) and the pixels' times."""
        if self.writer is None:
            return
        try:
            s = np.asarray(samples)
            order = tuple(channel_order)
            if order != self.channels:   # a resumed acquisition may list its channels otherwise
                s = s[:, [order.index(c) for c in self.channels], :]
            if s.dtype != np.int16 and s.dtype.kind == "i" and s.dtype.itemsize < 2:
                s = s.astype(np.int16)   # 8-bit records: widened without change
            tt = header_column(headers, "trigger_time_ns")
            ov = (header_column(headers, "overrange") != 0).astype(np.uint8)
            self.writer.append(s, tt, ov, t_pix_s)
            self.pixels_recorded += len(t_pix_s)
        except Exception as exc:
            self._fail(exc)

    def close(self, **final: Any) -> None:
        if self.writer is None:
            return
        try:
            self.writer.close(**final)
        except Exception as exc:
            self._fail(exc)

    def _fail(self, exc: Exception) -> None:
        self.error = f"{type(exc).__name__}: {exc}"
        log.warning("raw capture %s: recording stopped: %s (the committed chunks stay readable)",
                    self.writer.path if self.writer else "?", self.error)
        self.writer = None
