"""Simulated FPSA controller board: Cmod-S7 FPGA firmware + two HV583 drivers + the MEMS array,
as a byte-level peer of ``drivers/fpsa`` (§4.3.3 and Fig. 4-22; §4.2.1; §4.2.6; §4.3.6).

The simulator speaks the wire protocol of docs/protocols/fpsa.md through the pure codec
``drivers.fpsa.protocol``. Serve it on a pty (:class:`PtyServer`, the driver opens the slave path
like any serial device) or through the in-memory :class:`SimSerial` for tests. All time is the
shared :class:`~sim_devices.clock.VirtualClock`: every request and response advances it by its
UART wire time at the configured baud (10 bit times per byte).

Hardware modelled:

* Two HV583 converters (:class:`~sim_devices.fpsa.hv583.HV583`: 0.8 us full refresh, §4.3.3) whose
  registers power up RANDOM: until the host sends RESET the array shows garbage (many rows and
  columns on), the state is FAULT and STATUS flags HV_UNINITIALIZED.
* Wiring (§4.3.3): converter A output r drives row switch r, but only bonded rows are wired
  (default: one row in every four skipped, ``r % 4 == 3``); converter B output c drives column c.
  A pattern pixel on an unbonded row is NAKed with BAD_ROW_UNBONDED.
* MEMS switches (``sim_devices.world.mems``: pull-in/release hysteresis, first-order optical
  response); the HV supply (``hv_supply_v``) must exceed pull-in for anything to switch.
* The firmware steps an uploaded pattern on the virtual clock (``sim_devices.fpsa.triggers``). During a
  transition the old row/column is still partly on, so the capture windows see ghost beams
  exactly as the dynamics predict; :meth:`FpgaSim.triggers` reports them.

Faults (``sim_devices.faults``): :meth:`FpgaSim.stick_switch` makes one MEMS switch ignore its
drive from a virtual moment on (stuck on: every pixel of that row/column line emits whenever its
partner line is on; stuck off: its pixels never emit) until :meth:`FpgaSim.release_switch`; the
drive log itself is untouched (the HV583 still drives the line, the switch does not follow). The
transports take a :class:`~sim_devices.faults.SerialLineNoise` (byte drops, bit flips, both
directions), and :meth:`PtyServer.close` makes the device vanish from the host's point of view.

Parts: :class:`FpgaSim` is the byte interface (parser, retry cache, wire time), its lock, inspection
and the stuck-switch faults; it HOLDS the board (``board``: HV583 registers, line wiring, drive log,
``sim_devices.fpsa.board``), the firmware that commands it (``firmware``: state machine and command
handlers, ``sim_devices.fpsa.firmware``) and the chip optics that read it (``optics``: switch banks,
lit beams, triggers, ``sim_devices.fpsa.beams``). The drive-event log and stuck-switch intervals are
``sim_devices.fpsa.drive_log``, the transports ``sim_devices.fpsa.serial_port``.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

import numpy as np

from drivers.fpsa import protocol as p
from drivers.errors import CrcError, ProtocolError
from sim_devices.clock import VirtualClock
from sim_devices.faults import SerialLineNoise
from sim_devices.fpsa.beams import ChipOptics
from sim_devices.fpsa.board import FpgaConfig, FpsaBoard
from sim_devices.fpsa.drive_log import line_kind
from sim_devices.fpsa.firmware import Firmware
from sim_devices.fpsa.hv583 import HV583, default_bonded_rows
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.fpsa.serial_port import PtyServer, SimSerial
from sim_devices.fpsa.triggers import PixelSchedule, TriggerBatch


class FpgaSim:
    """The FPGA firmware + HV583 board + MEMS array, driven by bytes, timed by a virtual clock.

    Holds its board (:class:`~sim_devices.fpsa.board.FpsaBoard`), its firmware
    (:class:`~sim_devices.fpsa.firmware.Firmware`) and its chip optics
    (:class:`~sim_devices.fpsa.beams.ChipOptics`)."""

    def __init__(self, clock: VirtualClock, config: FpgaConfig | None = None) -> None:
        self.clock = clock
        self.config = config or FpgaConfig()
        self._lock = threading.RLock()
        self._parser = p.FrameParser()
        self._last_request: bytes | None = None
        self._last_response = b""
        self.rx_bytes = 0
        self.tx_bytes = 0
        self.executed = 0  # commands executed (cached retries are not counted)
        self._arm_counts: dict[float, int] = {}   # digitizer arm time -> its first trigger's number
        #: What the HV583 outputs carry (``supply``); the bench points it at the controller's HV output.
        self._supply: Callable[[], HvDrive] = lambda: HvDrive(self.config.hv_supply_v)
        self.board = FpsaBoard(self.config, lambda: self._supply())
        self.firmware = Firmware(self.board)
        self.optics = ChipOptics(self.board)
        self.firmware.power_up(self.clock.now())

    @property
    def supply(self) -> Callable[[], HvDrive]:
        """What the HV583 outputs carry: a callable answering the present :class:`HvDrive`."""
        return self._supply

    @supply.setter
    def supply(self, fn: Callable[[], HvDrive]) -> None:
        self._supply = fn

    # the firmware's and the board's state, for the bench and tests
    @property
    def state(self) -> p.State:
        return self.firmware.state

    @property
    def faults(self) -> p.FaultFlag:
        return self.firmware.faults

    @property
    def timing(self) -> p.Timing:
        return self.firmware.timing

    @property
    def hv_rows(self) -> HV583:
        return self.board.hv_rows

    @property
    def hv_cols(self) -> HV583:
        return self.board.hv_cols

    # --- byte-level interface -----------------------------------------------------------------
    def feed(self, data: bytes) -> bytes:
        """Consume bytes from the host; return the response bytes (possibly empty).

        The clock advances by the wire time of every received byte as it arrives (each frame is
        executed when its delimiter has arrived) and by the wire time of every response.
        """
        out = bytearray()
        with self._lock:
            pieces = bytes(data).split(b"\x00")
            for i, piece in enumerate(pieces):
                chunk = piece + (b"\x00" if i < len(pieces) - 1 else b"")
                if not chunk:
                    continue
                self.rx_bytes += len(chunk)
                self.clock.advance(p.wire_time_s(len(chunk), self.config.baudrate))
                for item in self._parser.feed_all(chunk):
                    resp = self._handle(item)
                    if resp:
                        self.tx_bytes += len(resp)
                        self.clock.advance(p.wire_time_s(len(resp), self.config.baudrate))
                        out += resp
        return bytes(out)

    def _handle(self, item: p.Frame | ProtocolError) -> bytes:
        if isinstance(item, ProtocolError):
            self.firmware.faults |= p.FaultFlag.LINK_ERRORS
            seq = getattr(item, "seq", None)
            cmd = getattr(item, "cmd", None)
            code = p.NakCode.BAD_CRC if isinstance(item, CrcError) else p.NakCode.BAD_LENGTH
            if seq is None:
                return b""  # not even a seq: nothing to answer to
            return p.encode_nak(seq, cmd if cmd is not None else 0, code)
        key = p.encode_inner(item.seq, item.cmd, item.payload)
        if key == self._last_request:
            return self._last_response  # a retry: answer again, do not execute again
        resp = self.firmware.execute(item, self.clock.now())
        self._last_request, self._last_response = key, resp
        self.executed += 1
        return resp

    # --- inspection (bench and tests) -------------------------------------------------------
    def status(self, now: float | None = None) -> p.Status:
        """What STATUS would report at ``now`` (clears LINK_ERRORS like a STATUS read does)."""
        with self._lock:
            return self.firmware.status(self.clock.now() if now is None else now)

    @property
    def total_triggers(self) -> int:
        """Triggers of the current (or last) run, up to a STOP if it was stopped; 0 if none."""
        with self._lock:
            return 0 if self.firmware.run is None else self.firmware.run.schedule.total_triggers

    @property
    def run_start_s(self) -> float | None:
        with self._lock:
            return None if self.firmware.run is None else self.firmware.run.schedule.run_start_s

    @property
    def schedule(self) -> PixelSchedule | None:
        with self._lock:
            return None if self.firmware.run is None else self.firmware.run.schedule

    def drive_events(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(kind 0=row 1=col, line, t_s, volts) of every line change so far (incl. a run's future)."""
        with self._lock:
            return self.board.events.arrays()

    def lines_high(self, t_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Row and column lines driven high at ``t_s`` (default now), from the drive log."""
        with self._lock:
            t_s = self.clock.now() if t_s is None else t_s
            return self.board.lines_high_before(float(np.nextafter(t_s, math.inf)))

    # --- stuck switches (fault injection) -------------------------------------------------------
    def _line_kind(self, line: str, index: int) -> int:
        return line_kind(line, index, self.config.rows, self.config.cols)

    def stick_switch(self, line: str, index: int, on: bool, t_s: float | None = None) -> None:
        """From ``t_s`` (default now) the MEMS switch of ``line`` ``index`` stays on/off."""
        kind = self._line_kind(line, index)
        with self._lock:
            t = self.clock.now() if t_s is None else float(t_s)
            self.board.stuck.stick(kind, int(index), on, t)
            self.board.touch()

    def release_switch(self, line: str, index: int, t_s: float | None = None) -> None:
        """From ``t_s`` (default now) the switch follows its drive again."""
        kind = self._line_kind(line, index)
        with self._lock:
            t = self.clock.now() if t_s is None else float(t_s)
            self.board.stuck.release(kind, int(index), t)
            self.board.touch()

    @property
    def stuck_switches(self) -> list[tuple[str, int, bool]]:
        """(line, index, on) of the switches stuck right now."""
        with self._lock:
            return self.board.stuck.stuck_now()

    def reset_link(self) -> None:
        """The serial link went away: a frame half-received is lost."""
        with self._lock:
            self._parser = p.FrameParser()

    # --- the light that leaves the chip (the chip optics, under the lock) ------------------------
    def pulls_in_every_switch(self) -> bool:
        """Whether the present drive pulls in every row and column switch."""
        with self._lock:
            return self.optics.pulls_in_every_switch()

    def lit_beams(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, mean path transmission) of beams leaving the chip during [t0, t1]."""
        with self._lock:
            return self.optics.lit_beams(t0_s, t1_s)

    def triggers(self, first: int, count: int, capture_s: float) -> TriggerBatch:
        """Triggers ``first .. first+count-1`` of the current run and their lit beams (does not
        advance the clock)."""
        with self._lock:
            run = self.firmware.run
            if run is None:
                raise ValueError("fpga: no run has been started (no triggers)")
            return self.optics.triggers(run.pattern, run.schedule, first, count, capture_s)

    def pattern_pixels(self, first_pixel: int, count: int) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the current run's pattern pixels ``first_pixel ..`` (at most ``count``;
        none without a run): what the run will point at next, for the bench's look-ahead."""
        with self._lock:
            run = self.firmware.run
            if run is None or count <= 0:
                return np.zeros(0, np.int16), np.zeros(0, np.int16)
            px = run.pattern[max(0, int(first_pixel)):max(0, int(first_pixel)) + int(count)]
            return px[:, 0].astype(np.int16), px[:, 1].astype(np.int16)

    def triggers_since(self, armed_s: float, first: int, count: int, capture_s: float) -> TriggerBatch:
        """Triggers ``first .. first+count-1`` counted from a digitizer's arm at ``armed_s``: the
        digitizer numbers the triggers it sees, whichever run of the board fired them, so segment 0
        of a digitizer armed before several runs is the first trigger of the first of them. Only the
        current run's triggers can be synthesized (the drive log keeps its lines only)."""
        with self._lock:
            run = self.firmware.run
            if run is None:
                raise ValueError("fpga: no run has been started (no triggers)")
            g = self._arm_counts.get(armed_s)
            if g is None:       # first read since this arm: while the runs around it are remembered
                g = self._arm_counts[armed_s] = self._triggers_fired_before(armed_s)
                while len(self._arm_counts) > 16:
                    del self._arm_counts[next(iter(self._arm_counts))]
            local = g + first - self.firmware.trigger_base
            if local < 0:
                raise ValueError(f"fpga: segments {first}..{first + count - 1} since the arm at {armed_s:.6f} s "
                                 "were fired by an earlier run, no longer in the drive log")
            return self.optics.triggers(run.pattern, run.schedule, local, count, capture_s)

    def _triggers_fired_before(self, t_s: float) -> int:
        """The board's number (triggers since power-up) of the first trigger a digitizer armed at
        ``t_s`` records. Armed during a run, it records that run from its first trigger: the simulator
        is lenient there (tests and tools start a pattern before they arm the digitizer, or arm again to
        re-read a run that has ended; lidard always arms first), so only runs started after the arm's
        run add to the count, and an arm after the current run's end re-reads the current run."""
        fw = self.firmware
        assert fw.run is not None
        runs = fw.retired + [(fw.run.schedule, fw.trigger_base)]
        for i in range(len(runs) - 1, -1, -1):
            sched, base = runs[i]
            if t_s >= sched.run_start_s:
                during = t_s < sched.end_s or i == len(runs) - 1
                return base if during else base + sched.total_triggers
        return runs[0][1]

    # --- transports ---------------------------------------------------------------------------
    def open_pipe(self, line: SerialLineNoise | None = None) -> SimSerial:
        return SimSerial(self, line)

    def serve_pty(self, line: SerialLineNoise | None = None) -> PtyServer:
        return PtyServer(self, line)


__all__ = ["FpgaConfig", "FpgaSim", "HV583", "PtyServer", "SimSerial", "default_bonded_rows"]
