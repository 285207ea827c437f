"""One acquisition lifecycle, ready -> start -> read -> stop, shared by scan, resume, linearization and self-test.

Dissertation §4.4.1 (Fig. 4-14): the AWG plays the laser's drive waveform on external trigger, the
FPGA steps the FPSA's switch pattern itself and triggers AWG and digitizer once per chirp period, and
the digitizer records ``triggers_per_pixel`` segments per pixel. There is no PC round trip per pixel:
the host only prepares, starts, reads segments by index and stops.

* :class:`AcquisitionPlan` is what to acquire (pixels, triggers, channels, rate, record length);
* :class:`Acquisition` is the context of one running acquisition (its plan, the digitizer's own
  record layout, where it starts inside the scan, the run's fault counters), passed to every step
  (after ophyd-async's detector ``_PrepareCtx``/trigger-info dataclasses) instead of closures;
* :class:`AcquisitionLifecycle` runs the steps; each driver call sits in :func:`on_device`, so a
  failure names its device (and the drivers' own ``.device`` wins).

Reads are idempotent (segments by index), so a failed batch is re-read up to ``BATCH_RETRIES`` times
with exponential backoff on the instrument's clock; a lost acquisition is :meth:`restart` ed from
the first pixel not yet read.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any
from collections.abc import Callable

import numpy as np

from drivers.usbtmc import DeviceDisconnected, DeviceStall, DeviceTimeout as UsbTimeout, UsbDeviceError
from drivers.retry import RetryPolicy

from ..config import Config
from ..physics.chirp import hold_segment_v, three_segment_drive_v, triangle_drive_v
from .devices import DeviceRegistry
from .errors import InstrumentError, SegmentsLost, on_device

AWG_RATE_HZ = 100e6          # drive samples: 16,000 per 160 us period
BATCH_RETRIES = 3            # re-reads of a failed batch of segments
BATCH_BACKOFF_S = 0.005      # first backoff between batch re-reads (doubles)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AcquisitionPlan:
    """What one acquisition records: every pixel of ``pixels`` ``triggers_per_pixel`` times."""

    pixels: np.ndarray                  # (n, 2) row, col in the order the FPGA steps them
    triggers_per_pixel: int
    channels: tuple[str, ...]           # digitizer channels ("beat", "mzi", "tap")
    fs_hz: float
    record_length: int                  # samples per segment
    bits: int

    @property
    def segments(self) -> int:
        return len(self.pixels) * int(self.triggers_per_pixel)

    def rest(self, from_pixel: int) -> AcquisitionPlan:
        """The same acquisition for the pixels from ``from_pixel`` on (a resume)."""
        return AcquisitionPlan(self.pixels[from_pixel:], self.triggers_per_pixel, self.channels, self.fs_hz,
                               self.record_length, self.bits)


@dataclass
class Acquisition:
    """The context of one prepared/running acquisition."""

    plan: AcquisitionPlan
    layout: Any                          # the digitizer's configure() reply: its channel order
    first_pixel: int = 0                 # index inside the whole scan of plan.pixels[0]
    faults: dict[str, Any] = field(default_factory=lambda: {"batch_retries": 0})
    started: bool = False
    # the digitizer's number of this acquisition's first segment: 0, or after the segments of earlier
    # FPGA runs on the same arm (:meth:`AcquisitionLifecycle.next_pattern`)
    segment_base: int = 0
    capacity: int = 0                    # segments the digitizer was armed for (0: plan.segments)

    @property
    def segments_end(self) -> int:
        """The digitizer's number of the first segment after this acquisition's."""
        return self.segment_base + self.plan.segments

    def channel_index(self, name: str) -> int:
        # the record lists channels in the digitizer's order (channel bits), not ours
        return self.layout.channels.index(name)


class AcquisitionLifecycle:
    """ready -> start -> read -> stop over the FPSA controller, the AWG and the digitizer."""

    def __init__(self, devices: DeviceRegistry, cfg: Config, sleep: Callable[[float], object]):
        self.devices = devices
        self.cfg = cfg
        self._sleep = sleep
        self._batch_retry = RetryPolicy.retries(BATCH_RETRIES, BATCH_BACKOFF_S, sleep)

    # -- ready ----------------------------------------------------------------------------------
    def load_drive(self, drive_v: np.ndarray) -> None:
        """Upload the laser drive waveform (volts) and play it on external trigger; refuses a waveform
        beyond the AWG's output range (devices.awg.max_output_v) before anything is uploaded."""
        d = np.asarray(drive_v, dtype=np.float64)
        peak = float(np.max(np.abs(d))) if d.size else 0.0
        limit = self.cfg.devices.awg.max_output_v
        if not (d.ndim == 1 and d.size >= 2 and np.all(np.isfinite(d)) and peak <= limit):
            raise InstrumentError(f"awg: refusing drive waveform (shape {d.shape}, peak {peak:.4g} V): it must be "
                                  f"finite and within the output range of +-{limit:g} V "
                                  "(devices.awg.max_output_v); nothing uploaded")
        awg = self.devices["awg"]
        with on_device("awg", "load drive"):
            awg.output(False)
            awg.set_sample_rate(AWG_RATE_HZ)
            awg.upload_waveform(d, units="volts")
            awg.set_trigger_external(True)
            awg.output(True)

    def ready(self, plan: AcquisitionPlan, *, drive_v: np.ndarray | None = None, first_pixel: int = 0,
              faults: dict[str, Any] | None = None, segments: int | None = None) -> Acquisition:
        """(Drive,) pattern and timing to the FPGA, then the digitizer configured and armed, for
        ``segments`` (default: the plan's; more lets later FPGA runs continue on the same arm)."""
        capacity = plan.segments if segments is None else int(segments)
        if capacity < plan.segments:
            raise InstrumentError(f"digitizer: {capacity} segments cannot hold the plan's {plan.segments}")
        if drive_v is not None:
            self.load_drive(drive_v)
        fpsa, dig = self.devices["fpsa"], self.devices["digitizer"]
        with on_device("fpsa", "pattern"):
            fpsa.upload_pattern(plan.pixels)
            fpsa.set_timing(settle_ns=int(self.cfg.scan.settle_s * 1e9), dwell_ns=0,
                            triggers_per_pixel=int(plan.triggers_per_pixel),
                            trigger_period_ns=int(round(self.cfg.chirp.period_s * 1e9)))
        with on_device("digitizer", "configure"):
            dig.abort()   # an acquisition a failed job left armed would lock the settings
            layout = dig.configure(channels=plan.channels, sample_rate_hz=plan.fs_hz,
                                   record_length=plan.record_length, segments=capacity, bits=plan.bits,
                                   input_range_v=self.cfg.adc.input_range_v,
                                   resolution_bits=self.cfg.adc.record_bits(plan.fs_hz, plan.bits),
                                   bandwidth_hz=self.cfg.adc.bandwidth_hz)
            dig.arm()
        return Acquisition(plan, layout, first_pixel, faults if faults is not None else {"batch_retries": 0},
                           capacity=capacity)

    def next_pattern(self, prev: Acquisition, plan: AcquisitionPlan,
                     faults: dict[str, Any] | None = None) -> Acquisition | None:
        """The next FPGA run on the digitizer acquisition ``prev`` runs on: only the pixel pattern goes
        to the FPGA (its timing stays), the digitizer stays armed and numbers the new run's segments
        after ``prev``'s. None when that is not possible (the digitizer's room is used up, or the plan
        records other channels, rate, length or triggers per pixel): then :meth:`ready` again."""
        a, b = prev.plan, plan
        same = (a.triggers_per_pixel == b.triggers_per_pixel and tuple(a.channels) == tuple(b.channels)
                and a.fs_hz == b.fs_hz and a.record_length == b.record_length and a.bits == b.bits)
        if not same or prev.segments_end + plan.segments > (prev.capacity or a.segments) or prev.started:
            return None
        with on_device("fpsa", "pattern"):
            self.devices["fpsa"].upload_pattern(plan.pixels)
        return Acquisition(plan, prev.layout, 0, faults if faults is not None else {"batch_retries": 0},
                           segment_base=prev.segments_end, capacity=prev.capacity)

    # -- start / read / stop --------------------------------------------------------------------
    def start(self, acq: Acquisition) -> None:
        fpsa = self.devices["fpsa"]
        with on_device("fpsa", "start"):
            fpsa.arm()
            fpsa.start()
        acq.started = True

    def read(self, acq: Acquisition, first: int, count: int) -> tuple[list[Any], np.ndarray]:
        """Segments ``first .. first + count - 1`` of this acquisition: (headers, samples); transient
        failures re-read the whole batch (bounded), then :class:`SegmentsLost`."""
        dig = self.devices["digitizer"]
        last: Exception | None = None
        try:
            for attempt in self._batch_retry.tries():   # waited BATCH_BACKOFF_S (doubling) before a re-read
                if attempt:
                    acq.faults["batch_retries"] += 1
                    log.warning("digitizer: re-reading segments %d..%d (attempt %d/%d) after %s",
                                first, first + count - 1, attempt + 1, BATCH_RETRIES + 1, last)
                with on_device("digitizer", "READ_SEGMENTS"):
                    try:
                        return dig.read_segments(acq.segment_base + first, count, acq.layout)
                    except DeviceStall as exc:
                        raise SegmentsLost(f"digitizer: refused READ_SEGMENTS({first},{count}): {exc}") from exc
                    except DeviceDisconnected as exc:
                        last = exc
                        try:
                            dig.reconnect(f"READ_SEGMENTS({first},{count})")
                        except Exception as exc2:
                            last = exc2
                    except (UsbTimeout, UsbDeviceError) as exc:
                        last = exc
            raise SegmentsLost(f"digitizer: segments {first}..{first + count - 1} could not be read after "
                               f"{BATCH_RETRIES + 1} attempts: {type(last).__name__}: {last}") from last
        finally:
            # a kept exception's traceback holds this frame, and this frame the exception: a cycle that
            # pins every caller's frame (and its arrays) until the cyclic collector runs
            last = None

    def read_all(self, acq: Acquisition, step: int,
                 done: Callable[[int, np.ndarray], None] | None = None) -> np.ndarray:
        """Every segment, ``step`` at a time (samples only); ``done(first, samples)`` after each read."""
        n = acq.plan.segments
        out = []
        for first in range(0, n, step):
            _, samples = self.read(acq, first, min(step, n - first))
            out.append(samples)
            if done is not None:
                done(first, samples)
        return np.concatenate(out) if out else np.zeros((0, len(acq.plan.channels), acq.plan.record_length))

    def stop(self, acq: Acquisition | None = None) -> None:
        """Stop the FPGA's pattern (no more triggers)."""
        with on_device("fpsa", "stop"):
            self.devices["fpsa"].stop()
        if acq is not None:
            acq.started = False

    def abort(self, acq: Acquisition | None = None) -> None:
        """Abort the digitizer's acquisition: one left armed locks its configuration for the next job."""
        try:
            with on_device("digitizer", "abort"):
                self.devices["digitizer"].abort()
        except Exception as exc:
            log.warning("digitizer abort after an early stop failed: %s", exc)

    def restart(self, acq: Acquisition, from_pixel: int) -> Acquisition:
        """Stop what is left of ``acq`` and start a new acquisition for its pixels from ``from_pixel``
        on (scan-wide index); the fault counters carry over."""
        try:
            self.stop(acq)
        except Exception as exc:  # the restart below is what matters; it fails loudly if needed
            log.warning("fpsa stop before resume failed: %s", exc)
        new = self.ready(acq.plan.rest(from_pixel - acq.first_pixel), first_pixel=from_pixel, faults=acq.faults)
        self.start(new)
        return new


def plain_drive(cfg: Config, static_tuning_hz_per_v: float) -> np.ndarray:
    """The unlinearized drive (volts) for the configured chirp: one triangle or three-segment period."""
    c = cfg.chirp
    if c.shape == "three_segment":
        return three_segment_drive_v(c.excursion_hz, c.ramp_s, c.cw_s, AWG_RATE_HZ, static_tuning_hz_per_v)
    return triangle_drive_v(c.excursion_hz, c.ramp_s, AWG_RATE_HZ, static_tuning_hz_per_v)


def drive_for_chirp(cfg: Config, drive_v: np.ndarray) -> np.ndarray:
    """``drive_v`` as one period of the configured chirp: a triangle period (e.g. a linearization
    stored before the three-segment chirp, or learned on its ramps) gets the constant segment
    appended (:func:`lidard.physics.chirp.hold_segment_v`); a drive of another length is refused."""
    c = cfg.chirp
    d = np.asarray(drive_v, dtype=np.float64)
    n_tri, n_period = int(round(2 * c.ramp_s * AWG_RATE_HZ)), int(round(c.period_s * AWG_RATE_HZ))
    if d.size == n_period:
        return d
    if d.size == n_tri:
        return hold_segment_v(d, n_period - n_tri)
    raise InstrumentError(f"awg: a drive of {d.size} samples is neither one chirp period ({n_period} samples, "
                          f"chirp.shape={c.shape!r}) nor one triangle period ({n_tri}); relinearize")
