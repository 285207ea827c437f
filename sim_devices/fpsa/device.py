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

Parts: this module is the board (configuration, HV583 line bookkeeping, the byte interface with its
retry cache, inspection, stuck-switch faults); the command handlers are ``sim_devices.fpsa.firmware``,
the drive-event log and stuck-switch intervals ``sim_devices.fpsa.drive_log``, the switch banks, lit
beams and triggers ``sim_devices.fpsa.beams``, the transports ``sim_devices.fpsa.serial_port``.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.fpsa import protocol as p
from drivers.fpsa.errors import ProtocolError

from sim_devices.clock import VirtualClock
from sim_devices.faults import SerialLineNoise
from sim_devices.fpsa.beams import ChipOptics
from sim_devices.fpsa.drive_log import COL, ROW, DriveEvents, StuckSwitches, line_kind, lines_high_before, settle_horizon_s
from sim_devices.fpsa.firmware import FirmwareCommands, _Run, _Upload
from sim_devices.fpsa.serial_port import PtyServer, SimSerial
from sim_devices.fpsa.hv583 import HV583, default_bonded_rows
from sim_devices.fpsa.hv_drive import HOLD_BOOST_S, HvDrive
from sim_devices.fpsa.triggers import PixelSchedule
from sim_devices.world.mems import COLUMN_SWITCH, ROW_SWITCH, SwitchBank, SwitchDynamics


@dataclass(frozen=True)
class FpgaConfig:
    rows: int = 128
    cols: int = 128
    bonded_rows: tuple[int, ...] | None = None  # None: default_bonded_rows(rows)
    baudrate: int = 3_000_000
    hv_supply_v: float = 40.0  # above the 32 V pull-in of §4.2.6
    seed: int = 0  # power-up register contents
    vendor: str = "lidard-sim"
    model: str = "FPSA128-HV583"
    firmware: tuple[int, int, int] = (1, 0, 0)
    row_dynamics: SwitchDynamics = ROW_SWITCH
    col_dynamics: SwitchDynamics = COLUMN_SWITCH
    beam_floor: float = 1e-6  # beams dimmer than this (path transmission) are not reported
    threshold_spread_v: float = 0.0  # 1-sigma switch-to-switch spread of pull-in/release (seeded)
    min_trigger_period_ns: int = 100

    def __post_init__(self) -> None:
        if not (1 <= self.rows <= HV583.N_OUTPUTS and 1 <= self.cols <= HV583.N_OUTPUTS):
            raise ValueError(f"rows/cols must be 1..128 (one HV583 each), got {self.rows}x{self.cols}")
        if not self.baudrate > 0:
            raise ValueError(f"baudrate must be > 0, got {self.baudrate!r}")

    @property
    def bonded(self) -> tuple[int, ...]:
        b = default_bonded_rows(self.rows) if self.bonded_rows is None else tuple(self.bonded_rows)
        if any(not 0 <= r < self.rows for r in b):
            raise ValueError(f"bonded_rows must lie in 0..{self.rows - 1}")
        return tuple(sorted(set(b)))


class FpgaSim(FirmwareCommands, ChipOptics):
    """The FPGA firmware + HV583 board + MEMS array, driven by bytes, timed by a virtual clock.

    The command handlers live in :class:`~sim_devices.fpsa.firmware.FirmwareCommands`, the light
    that leaves the chip (switch banks, beams, triggers) in :class:`~sim_devices.fpsa.beams.ChipOptics`."""

    def __init__(self, clock: VirtualClock, config: FpgaConfig | None = None) -> None:
        self.clock = clock
        self.config = config or FpgaConfig()
        self._lock = threading.RLock()
        self._bonded = self.config.bonded
        self._bonded_mask = np.zeros(self.config.rows, bool)
        self._bonded_mask[list(self._bonded)] = True
        self._parser = p.FrameParser()
        self._last_request: bytes | None = None
        self._last_response = b""
        self.rx_bytes = 0
        self.tx_bytes = 0
        self.executed = 0  # commands executed (cached retries are not counted)
        self._events = DriveEvents()
        self._holds = DriveEvents()  # hold-level drive after each pull-in boost (sim_devices.fpsa.hv_drive)
        #: What the HV583 outputs carry; the bench points this at the controller's HV output.
        self.supply: Callable[[], HvDrive] = lambda: HvDrive(self.config.hv_supply_v)
        self._banks: tuple[SwitchBank, SwitchBank] | None = None
        # intervals in which a switch ignores its drive (fault injection)
        self._stuck = StuckSwitches()
        # a line's drive history older than this (before its last switch-off) is dropped at each START
        self._settle_horizon_s = settle_horizon_s(self.config.row_dynamics, self.config.col_dynamics)
        self._power_up()

    # --- power-up and line bookkeeping ----------------------------------------------------------
    def _power_up(self) -> None:
        rng = np.random.default_rng(self.config.seed)
        self.hv_rows = HV583(rng)
        self.hv_cols = HV583(rng)
        self.state = p.State.FAULT
        self.faults = p.FaultFlag.HV_UNINITIALIZED
        if self._bonded_lines(self.hv_rows.outputs).sum() > 1:
            self.faults |= p.FaultFlag.MULTI_ROW
        self.timing = p.DEFAULT_TIMING
        self._upload: _Upload | None = None
        self._pattern: np.ndarray | None = None  # verified
        self._run: _Run | None = None
        self._run_slot = -1
        self._row_high = np.zeros(self.config.rows, bool)
        self._col_high = np.zeros(self.config.cols, bool)
        self._apply_outputs(self.clock.now())

    def _bonded_lines(self, outputs: np.ndarray) -> np.ndarray:
        return outputs[: self.config.rows] & self._bonded_mask

    def _apply_outputs(self, t_s: float) -> None:
        """Log drive events for every wired line whose HV583 output changed at ``t_s``."""
        rows = self._bonded_lines(self.hv_rows.outputs)
        cols = self.hv_cols.outputs[: self.config.cols]
        drive = self.supply()
        for kind, new, old in ((ROW, rows, self._row_high), (COL, cols, self._col_high)):
            changed = np.flatnonzero(new != old)
            if changed.size:
                self._events.add(kind, changed, t_s, np.where(new[changed], drive.hv_v, 0.0))
                rising = changed[new[changed]]
                if drive.holds and rising.size:
                    self._holds.add(kind, rising, t_s + HOLD_BOOST_S, drive.hold_v)
        self._row_high, self._col_high = rows.copy(), cols.copy()
        self._banks = None

    def _load_lines(self, t_s: float, row: int | None, col: int | None) -> float:
        """Firmware: shift one row bit and one column bit (never two rows), latch. Returns the
        latch time (t_s + 0.8 us)."""
        want_r = np.zeros(HV583.N_OUTPUTS, bool)
        want_c = np.zeros(HV583.N_OUTPUTS, bool)
        if row is not None:
            want_r[row] = True
        if col is not None:
            want_c[col] = True
        self.hv_rows.shift_in(want_r)
        self.hv_cols.shift_in(want_c)
        t_latch = t_s + HV583.refresh_s()
        self.hv_rows.latch_enable()
        self.hv_cols.latch_enable()
        self._apply_outputs(t_latch)
        return t_latch

    def _sync(self, now: float) -> None:
        """Bring the firmware state up to ``now`` (a run that ended becomes DONE)."""
        run = self._run
        if self.state == p.State.RUNNING and run is not None and now >= run.schedule.end_s:
            self.state = p.State.DONE
            self._finish_run_hardware()

    def _finish_run_hardware(self) -> None:
        # After the run the firmware leaves the registers cleared (the event log already holds
        # the lines-off events at the run's end).
        for hv in (self.hv_rows, self.hv_cols):
            hv.shift[:] = False
            hv.latch[:] = False
        self._row_high[:] = False
        self._col_high[:] = False

    def _cut_run(self, t_s: float) -> None:
        """STOP/RESET during a run: drop run events after ``t_s`` and switch its lines off."""
        run = self._run
        if run is None or self.state != p.State.RUNNING or t_s >= run.schedule.end_s:
            return
        sched = run.schedule
        # the run's events are one slot of the log: keep only what happened before the cut
        ev, k = self._events, self._run_slot
        keep = ev.t[k] < t_s
        ev.kind[k], ev.line[k], ev.t[k], ev.v[k] = (ev.kind[k][keep], ev.line[k][keep],
                                                    ev.t[k][keep], ev.v[k][keep])
        # whatever is still high just before the cut goes off at the cut (blanking)
        rows_high, cols_high = self._lines_high_before(t_s)
        for kind, high in ((ROW, rows_high), (COL, cols_high)):
            idx = np.flatnonzero(high)
            if idx.size:
                self._events.add(kind, idx, t_s, 0.0)
        self._run = _Run(run.pattern, dataclasses.replace(sched, cut_s=t_s))
        self._finish_run_hardware()
        self._banks = None

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
            self.faults |= p.FaultFlag.LINK_ERRORS
            seq = getattr(item, "seq", None)
            cmd = getattr(item, "cmd", None)
            code = p.NakCode.BAD_CRC if isinstance(item, p.CrcError) else p.NakCode.BAD_LENGTH
            if seq is None:
                return b""  # not even a seq: nothing to answer to
            return p.encode_nak(seq, cmd if cmd is not None else 0, code)
        key = p.encode_inner(item.seq, item.cmd, item.payload)
        if key == self._last_request:
            return self._last_response  # a retry: answer again, do not execute again
        resp = self._execute(item)
        self._last_request, self._last_response = key, resp
        self.executed += 1
        return resp

    # --- inspection (bench and tests) -------------------------------------------------------
    def status(self, now: float | None = None) -> p.Status:
        """What STATUS would report at ``now`` (clears LINK_ERRORS like a STATUS read does)."""
        with self._lock:
            now = self.clock.now() if now is None else now
            self._sync(now)
            idx = pixels = trig = 0
            if self._run is not None:
                s = self._run.schedule
                idx, pixels, trig = s.pattern_index(now), s.pixels_done(now), s.triggers_before(now)
            st = p.Status(self.state, self.faults, idx, pixels, trig)
            self.faults &= ~p.FaultFlag.LINK_ERRORS
            return st

    @property
    def total_triggers(self) -> int:
        """Triggers of the current (or last) run, up to a STOP if it was stopped; 0 if none."""
        with self._lock:
            return 0 if self._run is None else self._run.schedule.total_triggers

    @property
    def run_start_s(self) -> float | None:
        with self._lock:
            return None if self._run is None else self._run.schedule.run_start_s

    @property
    def schedule(self) -> PixelSchedule | None:
        with self._lock:
            return None if self._run is None else self._run.schedule

    def drive_events(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(kind 0=row 1=col, line, t_s, volts) of every line change so far (incl. a run's future)."""
        with self._lock:
            return self._events.arrays()

    def lines_high(self, t_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Row and column lines driven high at ``t_s`` (default now), from the drive log."""
        with self._lock:
            t_s = self.clock.now() if t_s is None else t_s
            return self._lines_high_before(np.nextafter(t_s, math.inf))

    def _lines_high_before(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        return lines_high_before(self._events, self.config.rows, self.config.cols, t_s)

    # --- stuck switches (fault injection) -------------------------------------------------------
    def _line_kind(self, line: str, index: int) -> int:
        return line_kind(line, index, self.config.rows, self.config.cols)

    def stick_switch(self, line: str, index: int, on: bool, t_s: float | None = None) -> None:
        """From ``t_s`` (default now) the MEMS switch of ``line`` ``index`` stays on/off."""
        kind = self._line_kind(line, index)
        with self._lock:
            t = self.clock.now() if t_s is None else float(t_s)
            self._stuck.stick(kind, int(index), on, t)
            self._banks = None

    def release_switch(self, line: str, index: int, t_s: float | None = None) -> None:
        """From ``t_s`` (default now) the switch follows its drive again."""
        kind = self._line_kind(line, index)
        with self._lock:
            t = self.clock.now() if t_s is None else float(t_s)
            self._stuck.release(kind, int(index), t)
            self._banks = None

    @property
    def stuck_switches(self) -> list[tuple[str, int, bool]]:
        """(line, index, on) of the switches stuck right now."""
        with self._lock:
            return self._stuck.stuck_now()

    def reset_link(self) -> None:
        """The serial link went away: a frame half-received is lost."""
        with self._lock:
            self._parser = p.FrameParser()

    # --- transports ---------------------------------------------------------------------------
    def open_pipe(self, line: SerialLineNoise | None = None) -> SimSerial:
        return SimSerial(self, line)

    def serve_pty(self, line: SerialLineNoise | None = None) -> PtyServer:
        return PtyServer(self, line)


__all__ = ["FpgaConfig", "FpgaSim", "HV583", "PtyServer", "SimSerial", "default_bonded_rows"]
