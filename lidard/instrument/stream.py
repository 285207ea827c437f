"""A stream of frames back to back over one bring-up (dissertation §4.1 random access, §5.2.2 adaptive scanning).

A scan brings laser and HV up, loads the drive, acquires one pattern and brings everything down. A
stream does the set-up once: outputs up and the drive loaded at the start, down at the end, and one
digitizer acquisition armed for ``ACQUISITION_SPAN_S`` of chirps that runs across frames: the
digitizer numbers the triggers it sees whichever FPGA run fired them, so between frames only the next
pixel pattern goes to the FPGA, which is armed and started again (it refuses a new pattern while it
runs: a frame is one FPGA run). The digitizer is set up again only when that arm's segments are used
up or a health check needed the digitizer. The batches of a frame are read, checked (safety) and
turned into points by the scan loop's own step (:meth:`ScanLoop.step`); this module only sequences
frames.

Time: every point's ``t`` counts from the stream's first trigger (on a simulated bench the scene's
motion refers to the same moment, :meth:`StreamLoop.run` pins it). A frame's record says where it
starts (``start_s``), how long its triggers ran (``hardware_time_s``), and the set-up gap before its
first trigger (``setup_s``: hardware time not spent triggering pixels; its share of the frame period
is the stream's per-frame overhead).

Linearization health: the job checks it before the stream; between frames it runs again when the
TEC reading moved by ``scan.recalibrate_delta_c`` since the last check or ``health_interval_s`` of
hardware time passed (the check needs its own acquisition, so the outputs cycle once). A check that
finds the chirp off stops the stream with the reason (frames so far kept): re-linearizing is the
worker's decision, as for scans.

Stopping: ``cancel`` (DELETE, Ctrl-C, SIGTERM), ``frames`` reached, a safety trip (outputs already
down, reason recorded), or a device failure: the frame in progress is delivered as a partial frame
and every finished frame has already been handed to ``on_frame``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..dsp.spectrum.jit import plan_path
from .acquisition import Acquisition
from .errors import describe_failure, driver_error
from .frames import Frame, FramePlan, Planner, StreamResult, pixel_period_s
from .scan_loop import BATCH_BYTES, ScanLoop, ScanPlan, ScanRun, batch_pixels, plan_scan
from .types import CalibrationResult, ScanRequest

log = logging.getLogger(__name__)

TEC_POLL_S = 1.0     # hardware time between TEC readings (one Modbus request each) during a stream
# Hardware time one digitizer acquisition spans in a stream: frames run on one arm until its segments are
# used up, then the digitizer is set up again (one frame's gap). 60 s of chirps is 375,000 segments at
# 160 us, far inside the digitizer's 2^24 segment counter (docs/protocols/digitizer.md).
ACQUISITION_SPAN_S = 60.0
# Hardware time of triggers per read inside a frame: a read waits for its last trigger, so the records of
# the frame's last read are still on the bus when its triggers end, and the next frame cannot start
# before they are read: shorter reads shorten that tail (the gap between frames) at a fixed cost per
# read. 5 ms: the tail of a 10 Hz frame is ~2 ms on sim.toml (records 3.7 kB per pixel over 40 MB/s).
FRAME_READ_S = 0.005
# ... and the frame's last read is this short: only its records are left on the bus after the last
# trigger (1 ms of triggers: ~4 pixels, 0.4 ms of read-out on sim.toml, against ~1.9 ms for a 5 ms read)
FRAME_TAIL_S = 0.001


def read_size(left: int, step: int, tail: int) -> int:
    """Pixels of the next read of a frame with ``left`` pixels to go: ``step`` at a time, then halving
    towards the last ``tail`` pixels, read on their own. A read's records cross the bus after its
    triggers; while the bus is at least twice as fast as the records are made (40 MB/s against 15 MB/s
    on sim.toml) each halved read is on the host before the next one's triggers end, so what is left
    on the bus after the frame's last trigger is the tail's records only."""
    if left <= tail:
        return left
    if left <= 2 * tail:
        return left - tail
    return min(step, -(-left // 2))


@dataclass
class _State:
    t0_ns: float | None = None          # the stream's first trigger (digitizer clock)
    end_ns: float | None = None         # end of the last record of the previous frame
    tec_c: float = math.nan             # TEC at the last health check
    checked_s: float = 0.0              # stream time of the last health check
    interval_s: float = 60.0            # hardware time between health checks
    tec_read_s: float = -math.inf
    history: list = field(default_factory=list)
    health: list = field(default_factory=list)
    acq: Acquisition | None = None      # the last frame's acquisition, when the next may run on its arm
    arms: int = 0                       # digitizer acquisitions set up (configure + arm) so far
    dsp_path: str | None = None         # every frame's DSP path, decided once (lidard.dsp.spectrum.jit)

    def start_s(self, frame_t0_ns: float | None) -> float:
        """A frame's start on the stream's time axis: its first trigger; for a frame that never
        triggered (a stop during its set-up), where the last frame ended, so frame times still grow and
        a rate over the kept frames stays defined (it read 0.0, the stream's first trigger)."""
        ref = self.end_ns if frame_t0_ns is None else frame_t0_ns
        return 0.0 if ref is None or self.t0_ns is None else (ref - self.t0_ns) * 1e-9


class StreamLoop:
    """Runs frames back to back on the scan loop's acquisition, safety and DSP machinery."""

    def __init__(self, loop: ScanLoop, *, health: Callable[[], Any] | None = None,
                 tec: Callable[[], float] | None = None, scene_clock: Callable[[bool], object] | None = None,
                 history_frames: int = 4, tec_poll_s: float = TEC_POLL_S):
        self.loop = loop
        self.cfg, self.lifecycle, self.safety = loop.cfg, loop.lifecycle, loop.safety
        self._health = health           # -> HealthCheck | None (laser and HV cycled by the check)
        self._tec = tec
        self._scene_clock = scene_clock  # simulated bench: hold the scene's clock across frames
        self.history_frames = history_frames
        self.tec_poll_s = tec_poll_s      # hardware time between TEC readings

    def base_plan(self, request: ScanRequest, calibration: CalibrationResult | None) -> ScanPlan:
        """The ADC, DSP and channels of every frame (the pixels are the planner's, frame by frame)."""
        req = dataclasses.replace(request, pattern="roi" if (request.rows or request.cols) else "raster",
                                  pixels=None)
        applied = self.loop.applied
        return plan_scan(self.cfg, self.loop.optics, req, applied.delay_or(self.cfg.monitor.delay_s),
                         applied.iq_imbalance,
                         (calibration.meta or {}).get("hold_profile") if calibration else None)

    def pixel_period_s(self, p: ScanPlan) -> float:
        return pixel_period_s(self.cfg, p.averages)

    def run(self, request: ScanRequest, planner: Planner, on_frame: Callable[[Frame], None],
            cancel: threading.Event, drive_v: np.ndarray, calibration: CalibrationResult | None = None, *,
            frames: int | None = None, health_interval_s: float = 60.0,
            on_points: Callable[[np.ndarray], None] | None = None) -> StreamResult:
        """Frames until ``frames`` are done or ``cancel`` is set (or a stop); each finished or
        partial frame goes to ``on_frame`` as soon as it is complete; ``on_points`` gets the points of
        every batch as they are processed (live viewers)."""
        if frames is not None and frames < 1:
            raise ValueError(f"frames: {frames} is not a positive number of frames")
        if not health_interval_s > 0:
            raise ValueError(f"health_interval_s: {health_interval_s} must be > 0")
        base = self.base_plan(request, calibration)
        st = _State(tec_c=self._read_tec(), interval_s=float(health_interval_s),
                    dsp_path=plan_path(base.dsp.spectrum_cells(base.n_pixels, base.averages) * (frames or 1)))
        cal_id = (calibration.meta or {}).get("id") if calibration else None
        count, stop_reason, safe = 0, None, None
        if self._scene_clock is not None:
            self._scene_clock(True)
        try:
            self.safety.bring_up()
            self.lifecycle.load_drive(drive_v)
            while (frames is None or count < frames) and not cancel.is_set():
                if count:
                    why = self._health_due(st)
                    if why is not None:
                        stop_reason = self._recheck(st, drive_v, why)
                        if stop_reason is not None:
                            break
                fp = planner(count, st.history)
                run, frame = self._frame(count, base, fp, st, cancel, cal_id, on_points)
                count += 1
                on_frame(frame)
                st.history = (st.history + [frame])[-self.history_frames:]
                if run.stop_reason is not None:
                    stop_reason, safe = run.stop_reason, run.safe
                    break
        except Exception as exc:        # set-up, planner or health check: the frames so far stand
            stop_reason = describe_failure(exc)
            log.warning("stream stopped after %d frames: %s", count, stop_reason)
        finally:
            if st.acq is not None:      # the arm the frames ran on has room left: end it
                self.lifecycle.abort(st.acq)
                st.acq = None
            try:
                if safe is not None:    # a safety stop: outputs already down (and read back)
                    self.safety.stop_watch()
                else:
                    self.safety.bring_down()
            finally:
                if self._scene_clock is not None:
                    self._scene_clock(False)
        hw = 0.0 if st.end_ns is None or st.t0_ns is None else (st.end_ns - st.t0_ns) * 1e-9
        meta = {"pixel_period_s": self.pixel_period_s(base), "calibration_id": cal_id,
                "adc": {"sample_rate_hz": base.adc.fs_hz, "record_length": base.adc.record_length},
                "dsp": base.dsp.sidecar(base.phase_noise, st.dsp_path), "simulated": self.loop.simulated,
                "health_interval_s": float(health_interval_s), "digitizer_arms": st.arms}
        if safe is not None:
            meta["safe_state"] = safe
        return StreamResult(count, hw, stop_reason, cancel.is_set(), st.health, meta)

    # -- one frame --------------------------------------------------------------------------------
    def _frame(self, index: int, base: ScanPlan, fp: FramePlan, st: _State, cancel: threading.Event,
               cal_id, on_points) -> tuple[ScanRun, Frame]:
        px = np.asarray(fp.pixels, dtype=np.int64).reshape(-1, 2)
        p = dataclasses.replace(base, pixels=px, acquisition=dataclasses.replace(base.acquisition, pixels=px))
        loop = self.loop
        run = loop.new_run(p, cal_id, flush_bytes=BATCH_BYTES, dsp_path=st.dsp_path)
        if len(px):
            try:
                acq = None if st.acq is None else self.lifecycle.next_pattern(st.acq, p.acquisition, run.faults)
                st.acq = None
                if acq is None:         # the first frame, or the last arm is used up: set the digitizer up
                    acq = self.lifecycle.ready(p.acquisition, faults=run.faults, segments=self._capacity(p))
                    st.arms += 1
                self.lifecycle.start(acq)
                step = min(batch_pixels(self.cfg, p), max(1, int(FRAME_READ_S / self.pixel_period_s(p))))
                tail = min(step, max(1, int(FRAME_TAIL_S / self.pixel_period_s(p))))
                while run.done < p.n_pixels and run.stop_reason is None:
                    if cancel.is_set():
                        run.cancelled = True
                        break
                    acq, accepted = loop.step(run, acq, read_size(p.n_pixels - run.done, step, tail))
                    if accepted and on_points is not None:
                        new = run.points.take_new()
                        if new is not None:
                            on_points(self._place(new, index, run, st))
                if run.stop_reason is None and self.safety.tripped is not None:
                    loop.safety_stop(run)
                try:
                    self.lifecycle.stop(acq)
                finally:
                    if run.done < p.n_pixels:
                        self.lifecycle.abort(acq)
                    else:               # the next frame may continue on this arm
                        st.acq = acq
            except Exception as exc:     # a device that stays down: this frame is the last (partial)
                run.stop_reason = describe_failure(exc)
                log.warning("stream frame %d failed: %s", index, run.stop_reason, exc_info=driver_error(exc))
                self.lifecycle.abort()   # logs its own failure: the stop reason is the first error
        pts = run.points.points()
        frame_t0 = run.hw_t0_ns
        if frame_t0 is not None:
            if st.t0_ns is None:
                st.t0_ns = frame_t0
            setup = 0.0 if st.end_ns is None else (frame_t0 - st.end_ns) * 1e-9
            st.end_ns = frame_t0 + run.hw_last_s * 1e9
        else:
            setup = 0.0
        pts = self._place(pts, index, run, st)
        frame = Frame(index, pts, px, run.done,
                      st.start_s(frame_t0),
                      run.hw_last_s, setup, self.pixel_period_s(p),
                      partial=run.done < p.n_pixels, stop_reason=run.stop_reason, trade=dict(fp.trade),
                      faults=dict(run.faults))
        return run, frame

    def _capacity(self, p: ScanPlan) -> int:
        """Segments a stream's digitizer acquisition is armed for: ACQUISITION_SPAN_S of chirps, at
        least the frame's."""
        return max(p.acquisition.segments, int(ACQUISITION_SPAN_S / self.cfg.chirp.period_s))

    @staticmethod
    def _place(pts: np.ndarray, index: int, run: ScanRun, st: _State) -> np.ndarray:
        """Frame index, and ``t`` moved from the frame's first trigger to the stream's."""
        pts = np.array(pts, copy=True)
        pts["frame"] = index
        if run.hw_t0_ns is not None and st.t0_ns is not None:
            pts["t"] += (run.hw_t0_ns - st.t0_ns) * 1e-9
        return pts

    # -- health -------------------------------------------------------------------------------------
    def _read_tec(self) -> float:
        if self._tec is None:
            return math.nan
        try:
            return float(self._tec())
        except Exception as exc:
            log.warning("stream: TEC unreadable: %s", exc)
            return math.nan

    def _now_s(self, st: _State) -> float:
        return 0.0 if st.end_ns is None or st.t0_ns is None else (st.end_ns - st.t0_ns) * 1e-9

    def _health_due(self, st: _State) -> str | None:
        """Why the linearization must be checked again before the next frame, or None."""
        if self._health is None:
            return None
        now = self._now_s(st)
        if now - st.checked_s >= st.interval_s:
            return f"{st.interval_s:g} s of hardware time since the last check"
        if now - st.tec_read_s >= self.tec_poll_s:
            st.tec_read_s = now
            tec = self._read_tec()
            if math.isfinite(tec) and math.isfinite(st.tec_c) and abs(tec - st.tec_c) > self.cfg.scan.recalibrate_delta_c:
                return f"TEC moved {tec - st.tec_c:+.2f} C since the last check"
        return None

    def _recheck(self, st: _State, drive_v: np.ndarray, why: str) -> str | None:
        """Run the health check between frames; answers the stop reason when the chirp is off."""
        if self._health is None:        # no check configured: nothing is ever due (_health_due)
            return None
        if st.acq is not None:          # the check sets the digitizer up for itself
            self.lifecycle.abort(st.acq)
            st.acq = None
        check = self._health()          # its own acquisition; outputs up and down around it
        st.checked_s, st.tec_c = self._now_s(st), self._read_tec()
        if check is not None:
            st.health.append({"at_s": st.checked_s, "why": why, "residual_hz": check.residual_hz,
                              "threshold_hz": check.threshold_hz, "exceeded": bool(check.exceeded)})
            if check.exceeded:
                return f"linearization health check between frames: {check.reason()}"
        self.safety.bring_up()
        self.lifecycle.load_drive(drive_v)
        return None

