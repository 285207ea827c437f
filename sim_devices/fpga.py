"""Simulated FPSA controller board: Cmod-S7 FPGA firmware + two HV583 drivers + the MEMS array,
as a byte-level peer of ``drivers/fpsa`` (§4.3.3 and Fig. 4-22; §4.2.1; §4.2.6; §4.3.6).

The simulator speaks the wire protocol of docs/protocols/fpsa.md through the pure codec
``drivers.fpsa.protocol``. Serve it on a pty (:class:`PtyServer`, the driver opens the slave path
like any serial device) or through the in-memory :class:`SimSerial` for tests. All time is the
shared :class:`~sim_devices.clock.VirtualClock`: every request and response advances it by its
UART wire time at the configured baud (10 bit times per byte).

Hardware modelled:

* Two HV583 128-channel serial-to-parallel converters, each with four 32-bit shift registers
  clocked in parallel at 40 MHz, a latch, blanking and polarity (:class:`HV583`). Loading all
  256 lines takes 32 clocks = 0.8 us, i.e. the 1.25 MHz full-refresh rate of §4.3.3 (256 bits
  down a single serial line would take 6.4 us). Shift registers and latches power up with
  RANDOM contents and the outputs live: until the host sends RESET the array shows garbage
  (many rows and columns on), the state is FAULT and STATUS flags HV_UNINITIALIZED.
* Wiring (§4.3.3): converter A output r drives row switch r, but only bonded rows are wired
  (default: one row in every four skipped, ``r % 4 == 3``); converter B output c drives column c.
  A pattern pixel on an unbonded row is NAKed with BAD_ROW_UNBONDED.
* MEMS switches (``sim_devices.world.mems``): pull-in 32 V / release 29 V, first-order optical
  response (rows 1 us, columns 2.7 us on / 2.0 us off, command -> 90 %). The HV supply
  (``hv_supply_v``) must exceed pull-in for anything to switch.
* The firmware steps an uploaded pattern on the virtual clock (``sim_devices.triggers``). During a
  transition the old row/column is still partly on, so the capture windows see ghost beams
  exactly as the dynamics predict; :meth:`FpgaSim.triggers` reports them.

Faults (``sim_devices.faults``): :meth:`FpgaSim.stick_switch` makes one MEMS switch ignore its
drive from a virtual moment on (stuck on: every pixel of that row/column line emits whenever its
partner line is on; stuck off: its pixels never emit) until :meth:`FpgaSim.release_switch`; the
drive log itself is untouched (the HV583 still drives the line, the switch does not follow). The
transports take a :class:`~sim_devices.faults.SerialLineNoise` (byte drops, bit flips, both
directions), and :meth:`PtyServer.close` makes the device vanish from the host's point of view.
"""

from __future__ import annotations

import dataclasses
import math
import os
import select
import threading
import tty
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers.fpsa import protocol as p
from drivers.fpsa.errors import LengthError, PayloadError, ProtocolError

from .clock import VirtualClock
from .faults import SerialLineNoise
from .hv_drive import HOLD_BOOST_S, HvDrive, valid_holds
from .triggers import PixelSchedule, TriggerBatch
from .world.mems import (
    COLUMN_SWITCH,
    ROW_SWITCH,
    SwitchBank,
    SwitchDynamics,
    mean_path_transmission,
    switch_thresholds,
)

ROW, COL = 0, 1  # line kinds in the drive-event log


class HV583:
    """One HV583: 128 HV outputs fed by four 32-bit shift registers clocked in parallel.

    Register k, bit j drives output ``32 k + j`` after the latch-enable pulse. Data enters each
    register at bit 0 and moves one bit up per clock, so the bit clocked first ends up at bit 31.
    ``blank`` forces every output low; ``polarity_inverted`` inverts all outputs.
    """

    N_OUTPUTS = 128
    N_REGISTERS = 4
    REGISTER_BITS = 32
    MAX_CLOCK_HZ = 40e6

    def __init__(self, rng: np.random.Generator) -> None:
        # Power-up: registers and latches hold whatever the flip-flops settled to.
        self.shift = rng.integers(0, 2, (self.N_REGISTERS, self.REGISTER_BITS)).astype(bool)
        self.latch = rng.integers(0, 2, self.N_OUTPUTS).astype(bool)
        self.blank = False
        self.polarity_inverted = False
        self.clocks = 0

    def clock_in(self, bits: np.ndarray) -> None:
        """One shift clock: ``bits`` (4,) enter bit 0 of the four registers."""
        self.shift[:, 1:] = self.shift[:, :-1].copy()
        self.shift[:, 0] = np.asarray(bits, bool)
        self.clocks += 1

    def shift_in(self, outputs: np.ndarray) -> int:
        """Clock in a full frame so that after :meth:`latch_enable` output o == outputs[o].
        Returns the number of clocks used (32)."""
        want = np.asarray(outputs, bool).reshape(self.N_REGISTERS, self.REGISTER_BITS)
        for j in range(self.REGISTER_BITS - 1, -1, -1):
            self.clock_in(want[:, j])
        return self.REGISTER_BITS

    def latch_enable(self) -> None:
        self.latch = self.shift.reshape(-1).copy()

    @property
    def outputs(self) -> np.ndarray:
        if self.blank:
            return np.zeros(self.N_OUTPUTS, bool)
        return self.latch ^ self.polarity_inverted

    @classmethod
    def refresh_s(cls) -> float:
        """Time to reload every output: 32 clocks at 40 MHz = 0.8 us (1.25 MHz refresh)."""
        return cls.REGISTER_BITS / cls.MAX_CLOCK_HZ


def default_bonded_rows(rows: int = 128) -> tuple[int, ...]:
    """§4.3.3: "one signal in every four rows skipped" -> rows with r % 4 == 3 not bonded."""
    return tuple(r for r in range(rows) if r % 4 != 3)


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


class _Nak(Exception):
    def __init__(self, code: p.NakCode, detail: int | None = None) -> None:
        self.code = code
        self.detail = detail


@dataclass
class _Run:
    pattern: np.ndarray  # (n, 2) uint8
    schedule: PixelSchedule


@dataclass
class _Upload:
    total: int
    crc: int
    data: np.ndarray  # (total, 2) uint8
    received: np.ndarray  # (total,) bool


@dataclass
class _Events:
    """Append-only log of HV line drive changes: (kind, line, t_s, volts)."""

    kind: list[np.ndarray] = field(default_factory=list)
    line: list[np.ndarray] = field(default_factory=list)
    t: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)

    def add(self, kind, line, t, v) -> None:
        line = np.atleast_1d(np.asarray(line, np.int64))
        n = line.size
        self.kind.append(np.broadcast_to(np.asarray(kind, np.int8), (n,)).copy())
        self.line.append(line)
        self.t.append(np.broadcast_to(np.asarray(t, np.float64), (n,)).copy())
        self.v.append(np.broadcast_to(np.asarray(v, np.float64), (n,)).copy())

    def arrays(self):
        if not self.kind:
            z = np.zeros(0)
            return z.astype(np.int8), z.astype(np.int64), z, z
        return (np.concatenate(self.kind), np.concatenate(self.line), np.concatenate(self.t),
                np.concatenate(self.v))


class FpgaSim:
    """The FPGA firmware + HV583 board + MEMS array, driven by bytes, timed by a virtual clock."""

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
        self._events = _Events()
        self._holds = _Events()  # hold-level drive after each pull-in boost (sim_devices.hv_drive)
        #: What the HV583 outputs carry; the bench points this at the controller's HV output.
        self.supply: Callable[[], HvDrive] = lambda: HvDrive(self.config.hv_supply_v)
        self._banks: tuple[SwitchBank, SwitchBank] | None = None
        # (kind, line) -> [(t_from, t_to, on)]: intervals in which that switch ignores its drive
        self._stuck: dict[tuple[int, int], list[list]] = {}
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

    def _execute(self, frame: p.Frame) -> bytes:
        now = self.clock.now()
        self._sync(now)
        try:
            cmd = p.Cmd(frame.cmd)
        except ValueError:
            return p.encode_nak(frame.seq, frame.cmd, p.NakCode.UNKNOWN_CMD)
        handler = self._HANDLERS.get(cmd)
        if handler is None:
            return p.encode_nak(frame.seq, frame.cmd, p.NakCode.UNKNOWN_CMD)
        if self.state == p.State.FAULT and cmd not in (p.Cmd.IDENTIFY, p.Cmd.STATUS, p.Cmd.RESET):
            return p.encode_nak(frame.seq, frame.cmd, p.NakCode.BAD_STATE)
        try:
            data = handler(self, frame.payload, now)
        except _Nak as nak:
            return p.encode_nak(frame.seq, frame.cmd, nak.code, nak.detail)
        except LengthError:
            return p.encode_nak(frame.seq, frame.cmd, p.NakCode.BAD_LENGTH)
        except PayloadError:
            return p.encode_nak(frame.seq, frame.cmd, p.NakCode.OUT_OF_RANGE)
        return p.encode_ack(frame.seq, frame.cmd, data or b"")

    # --- command handlers ---------------------------------------------------------------------
    def _require_config_state(self) -> None:
        if self.state not in (p.State.IDLE, p.State.DONE, p.State.ARMED):
            raise _Nak(p.NakCode.BAD_STATE)

    @staticmethod
    def _no_payload(payload: bytes) -> None:
        if payload:
            raise _Nak(p.NakCode.BAD_LENGTH)

    def _cmd_identify(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        c = self.config
        return p.Identity(c.vendor, c.model, c.firmware, c.rows, c.cols, self._bonded).pack()

    def _cmd_reset(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        self._cut_run(now)
        # Firmware reset: blank, clock zeros through every register, latch, set polarity,
        # un-blank. Blanking first means the garbage disappears at once, not after 0.8 us.
        for hv in (self.hv_rows, self.hv_cols):
            hv.blank = True
        self._apply_outputs(now)
        for hv in (self.hv_rows, self.hv_cols):
            hv.shift_in(np.zeros(HV583.N_OUTPUTS, bool))
            hv.latch_enable()
            hv.polarity_inverted = False
            hv.blank = False
        self._apply_outputs(now + HV583.refresh_s())
        self.state = p.State.IDLE
        self.faults = p.FaultFlag.NONE
        self.timing = p.DEFAULT_TIMING
        self._upload = None
        self._pattern = None
        self._run = None
        return b""

    def _check_pixel(self, row: int, col: int, index: int | None) -> None:
        if not (0 <= row < self.config.rows and 0 <= col < self.config.cols):
            raise _Nak(p.NakCode.OUT_OF_RANGE, index)
        if not self._bonded_mask[row]:
            raise _Nak(p.NakCode.BAD_ROW_UNBONDED, index)

    def _cmd_set_pixel(self, payload: bytes, now: float) -> bytes:
        row, col = p.decode_set_pixel(payload)
        self._require_config_state()
        self._check_pixel(row, col, None)
        self._load_lines(now, row, col)
        self.state = p.State.IDLE
        return b""

    def _cmd_clear(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        self._require_config_state()
        self._load_lines(now, None, None)
        self.state = p.State.IDLE
        return b""

    def _cmd_pattern_begin(self, payload: bytes, now: float) -> bytes:
        total, crc = p.decode_pattern_begin(payload)
        self._require_config_state()
        if not 1 <= total <= self.config.rows * self.config.cols:
            raise _Nak(p.NakCode.OUT_OF_RANGE)
        self._upload = _Upload(total, crc, np.zeros((total, 2), np.uint8), np.zeros(total, bool))
        self._pattern = None
        self.state = p.State.IDLE
        return b""

    def _cmd_pattern_chunk(self, payload: bytes, now: float) -> bytes:
        chunk = p.decode_pattern_chunk(payload)
        up = self._upload
        if up is None or self.state not in (p.State.IDLE, p.State.DONE):
            raise _Nak(p.NakCode.BAD_STATE)
        if chunk.offset + chunk.count > up.total or chunk.count == 0:
            raise _Nak(p.NakCode.OUT_OF_RANGE, chunk.offset)
        if p.crc32(chunk.pixel_bytes) != chunk.crc32:
            raise _Nak(p.NakCode.CHUNK_CRC, chunk.offset)
        px = p.unpack_pixels(chunk.pixel_bytes).astype(np.int64)
        r, c = px[:, 0], px[:, 1]
        bad_range = (r >= self.config.rows) | (c >= self.config.cols)
        bad_bond = ~bad_range & ~self._bonded_mask[np.minimum(r, self.config.rows - 1)]
        bad = bad_range | bad_bond
        if bad.any():
            i = int(np.argmax(bad))
            code = p.NakCode.OUT_OF_RANGE if bad_range[i] else p.NakCode.BAD_ROW_UNBONDED
            raise _Nak(code, chunk.offset + i)
        up.data[chunk.offset: chunk.offset + chunk.count] = px
        up.received[chunk.offset: chunk.offset + chunk.count] = True
        return b""

    def _cmd_pattern_end(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        up = self._upload
        if up is None or self.state not in (p.State.IDLE, p.State.DONE):
            raise _Nak(p.NakCode.BAD_STATE)
        if not up.received.all():
            self.faults |= p.FaultFlag.PATTERN_INVALID
            raise _Nak(p.NakCode.PATTERN_INCOMPLETE, int(np.argmin(up.received)))
        if p.crc32(up.data.tobytes()) != up.crc:
            self.faults |= p.FaultFlag.PATTERN_INVALID
            self._upload = None
            raise _Nak(p.NakCode.PATTERN_CRC)
        self._pattern = up.data.copy()
        self._upload = None
        self.faults &= ~p.FaultFlag.PATTERN_INVALID
        return b""

    def _cmd_set_timing(self, payload: bytes, now: float) -> bytes:
        timing = p.Timing.unpack(payload)
        self._require_config_state()
        if timing.triggers_per_pixel < 1 or timing.trigger_period_ns < self.config.min_trigger_period_ns:
            raise _Nak(p.NakCode.BAD_TIMING)
        self.timing = timing
        self.state = p.State.IDLE
        return b""

    def _cmd_arm(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        self._require_config_state()
        if self._pattern is None:
            raise _Nak(p.NakCode.BAD_STATE)
        self.state = p.State.ARMED
        return b""

    def _cmd_start(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        if self.state != p.State.ARMED or self._pattern is None:
            raise _Nak(p.NakCode.BAD_STATE)
        tm = self.timing
        sched = PixelSchedule(
            run_start_s=now, n_pixels=int(self._pattern.shape[0]), refresh_s=HV583.refresh_s(),
            settle_s=tm.settle_ns * 1e-9, trigger_period_s=tm.trigger_period_ns * 1e-9,
            triggers_per_pixel=tm.triggers_per_pixel, dwell_s=tm.dwell_ns * 1e-9)
        self._run = _Run(self._pattern.copy(), sched)
        self._log_run_events(self._run)
        self.state = p.State.RUNNING
        return b""

    def _log_run_events(self, run: _Run) -> None:
        """Every line change of the whole run, in closed form (one event list, cut on STOP)."""
        sched = run.schedule
        rows = run.pattern[:, 0].astype(np.int64)
        cols = run.pattern[:, 1].astype(np.int64)
        n = rows.size
        latch = sched.latch_s(np.arange(n))
        drive = self.supply()
        v = drive.hv_v
        kinds, lines, ts, vs = [], [], [], []

        def add(k, line, t, volts):
            kinds.append(np.full(line.size, k, np.int8))
            lines.append(line)
            ts.append(np.asarray(t, np.float64))
            vs.append(np.full(line.size, volts))

        for k, seq, high in ((ROW, rows, self._row_high), (COL, cols, self._col_high)):
            # first latch: whatever was on before the run goes off, pixel 0 goes on
            pre = np.flatnonzero(high)
            pre = pre[pre != seq[0]]
            add(k, pre, np.full(pre.size, latch[0]), 0.0)
            if not high[seq[0]]:
                add(k, seq[:1], latch[:1], v)
            ch = np.flatnonzero(seq[1:] != seq[:-1]) + 1
            # off-then-on at the same latch time; the stable order keeps "off" first
            add(k, seq[ch - 1], latch[ch], 0.0)
            add(k, seq[ch], latch[ch], v)
            add(k, seq[-1:], np.array([sched.natural_end_s]), 0.0)
        self._run_slot = len(self._events.kind)
        all_k, all_l, all_t, all_v = (np.concatenate(kinds), np.concatenate(lines),
                                      np.concatenate(ts), np.concatenate(vs))
        self._events.add(all_k, all_l, all_t, all_v)
        rising = all_v > 0
        if drive.holds and rising.any():  # holds cut short by a line change are dropped later
            self._holds.add(all_k[rising], all_l[rising], all_t[rising] + HOLD_BOOST_S, drive.hold_v)
        self._row_high[:] = False
        self._col_high[:] = False
        self._banks = None

    def _cmd_stop(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        if self.state == p.State.RUNNING:
            self._cut_run(now)
        else:
            for hv in (self.hv_rows, self.hv_cols):
                hv.shift_in(np.zeros(HV583.N_OUTPUTS, bool))
                hv.latch_enable()
            self._apply_outputs(now + HV583.refresh_s())
        self.state = p.State.IDLE
        return b""

    def _cmd_status(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        return self.status(now).pack()

    _HANDLERS = {
        p.Cmd.IDENTIFY: _cmd_identify,
        p.Cmd.RESET: _cmd_reset,
        p.Cmd.SET_PIXEL: _cmd_set_pixel,
        p.Cmd.CLEAR: _cmd_clear,
        p.Cmd.PATTERN_BEGIN: _cmd_pattern_begin,
        p.Cmd.PATTERN_CHUNK: _cmd_pattern_chunk,
        p.Cmd.PATTERN_END: _cmd_pattern_end,
        p.Cmd.SET_TIMING: _cmd_set_timing,
        p.Cmd.ARM: _cmd_arm,
        p.Cmd.START: _cmd_start,
        p.Cmd.STOP: _cmd_stop,
        p.Cmd.STATUS: _cmd_status,
    }

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
        kinds, lines, ts, vs = self._events.arrays()
        out = []
        for k, n in ((ROW, self.config.rows), (COL, self.config.cols)):
            high = np.zeros(n, bool)
            m = (kinds == k) & (ts < t_s)
            order = np.argsort(ts[m], kind="stable")
            high[lines[m][order]] = vs[m][order] > 0  # later events overwrite earlier ones
            out.append(high)
        return out[0], out[1]

    def _switch_banks(self) -> tuple[SwitchBank, SwitchBank]:
        if self._banks is None:
            kinds, lines, ts, vs = self._events.arrays()
            banks = []
            for k, n, dyn in ((ROW, self.config.rows, self.config.row_dynamics),
                              (COL, self.config.cols, self.config.col_dynamics)):
                ln, t, v = self._with_holds(k, kinds, lines, ts, vs)
                ln, t, v = self._with_stuck(k, ln, t, v)
                thresholds = switch_thresholds(n, dyn, self.config.threshold_spread_v,
                                               [self.config.seed, 0x4B5, k])
                banks.append(SwitchBank(n, dyn, ln, t, v, thresholds=thresholds))
            self._banks = (banks[0], banks[1])
        return self._banks

    def _with_holds(self, kind: int, kinds, lines, ts, vs):
        """Drive events of one line kind, with the hold-level events that still apply."""
        m = kinds == kind
        ln, t, v = lines[m], ts[m], vs[m]
        hk, hl, ht, hv = self._holds.arrays()
        hm = hk == kind
        keep = valid_holds(ln, t, v, hl[hm], ht[hm])
        if not keep.any():
            return ln, t, v
        return (np.concatenate([ln, hl[hm][keep]]), np.concatenate([t, ht[hm][keep]]),
                np.concatenate([v, hv[hm][keep]]))

    def pulls_in_every_switch(self) -> bool:
        """Whether the present drive pulls in every row and column switch (the bench can then
        take the commanded pixel for the lit one when it skips the switch dynamics)."""
        with self._lock:
            rows_bank, cols_bank = self._switch_banks()
            hv = self.supply().hv_v
            return bool(hv >= rows_bank.pull_in_v.max() and hv >= cols_bank.pull_in_v.max())

    # --- stuck switches (fault injection) -------------------------------------------------------
    def _with_stuck(self, kind: int, lines: np.ndarray, ts: np.ndarray, vs: np.ndarray):
        """The drive events a switch actually follows: inside a stuck interval [t0, t1) its own
        events are ignored and it is held on (infinite drive) or off (0 V); at t1 it picks up the
        drive the HV583 holds at that moment."""
        extra_l, extra_t, extra_v = [], [], []
        keep = np.ones(lines.size, bool)
        for (k, line), intervals in self._stuck.items():
            if k != kind:
                continue
            mine = lines == line
            for t0, t1, on in intervals:
                keep &= ~(mine & (ts >= t0) & (ts < t1))
                extra_l.append(line)
                extra_t.append(t0)
                extra_v.append(math.inf if on else 0.0)
                if math.isfinite(t1):
                    before = np.flatnonzero(mine & (ts < t1))
                    drive = 0.0
                    if before.size:
                        last = before[np.argsort(ts[before], kind="stable")[-1]]
                        drive = float(vs[last])
                    extra_l.append(line)
                    extra_t.append(t1)
                    extra_v.append(drive)
        if not extra_l:
            return lines, ts, vs
        # the added events go first: at equal times SwitchBank keeps the given order, so the
        # stuck/release event precedes any drive event logged for the same instant
        return (np.concatenate([np.asarray(extra_l, np.int64), lines[keep]]),
                np.concatenate([np.asarray(extra_t, np.float64), ts[keep]]),
                np.concatenate([np.asarray(extra_v, np.float64), vs[keep]]))

    def _line_kind(self, line: str, index: int) -> int:
        if line not in ("row", "col"):
            raise ValueError(f"fpga: switch line must be 'row' or 'col', got {line!r}")
        n = self.config.rows if line == "row" else self.config.cols
        if not (isinstance(index, (int, np.integer)) and 0 <= index < n):
            raise ValueError(f"fpga: {line} index must be 0..{n - 1}, got {index!r}")
        return ROW if line == "row" else COL

    def stick_switch(self, line: str, index: int, on: bool, t_s: float | None = None) -> None:
        """From ``t_s`` (default now) the MEMS switch of ``line`` ``index`` stays on/off."""
        kind = self._line_kind(line, index)
        with self._lock:
            t = self.clock.now() if t_s is None else float(t_s)
            intervals = self._stuck.setdefault((kind, int(index)), [])
            if intervals and math.isinf(intervals[-1][1]):
                intervals[-1][1] = t  # re-sticking ends the previous interval
            intervals.append([t, math.inf, bool(on)])
            self._banks = None

    def release_switch(self, line: str, index: int, t_s: float | None = None) -> None:
        """From ``t_s`` (default now) the switch follows its drive again."""
        kind = self._line_kind(line, index)
        with self._lock:
            t = self.clock.now() if t_s is None else float(t_s)
            for iv in self._stuck.get((kind, int(index)), []):
                if math.isinf(iv[1]):
                    iv[1] = max(t, iv[0])
            self._banks = None

    @property
    def stuck_switches(self) -> list[tuple[str, int, bool]]:
        """(line, index, on) of the switches stuck right now."""
        with self._lock:
            return [("row" if k == ROW else "col", line, iv[-1][2])
                    for (k, line), iv in self._stuck.items() if iv and math.isinf(iv[-1][1])]

    def _candidate_rows(self) -> np.ndarray:
        # unbonded rows have no drive, but a row switch stuck on still passes light
        extra = [line for (k, line), ivs in self._stuck.items()
                 if k == ROW and any(on for _, _, on in ivs)]
        return np.asarray(sorted(set(self._bonded) | set(extra)), np.int64)

    def reset_link(self) -> None:
        """The serial link went away: a frame half-received is lost."""
        with self._lock:
            self._parser = p.FrameParser()

    def _beams(self, t0: np.ndarray, t1: np.ndarray, dwell: np.ndarray | None = None):
        """(window, row, col, transmission) of every beam above the floor in each window.

        ``dwell`` (optional, one id per window, non-decreasing): windows with the same id belong to
        one pixel dwell. Candidate switches are then found once per dwell, over the dwell's whole
        span (a switch that may be lit in a window may be lit in any span containing it: levels are
        monotone between events and an ON command inside is caught), and the exact transmissions
        are computed per window for those candidates only (issue 18: the averages of a pixel no
        longer evaluate every switch each)."""
        rows_bank, cols_bank = self._switch_banks()
        floor = self.config.beam_floor
        bonded = self._candidate_rows()
        if dwell is None:
            span0, span1, of = t0, t1, np.arange(t0.size)
        else:
            starts = np.flatnonzero(np.r_[True, dwell[1:] != dwell[:-1]])
            ends = np.r_[starts[1:], dwell.size]
            span0, span1 = np.minimum.reduceat(t0, starts), np.maximum.reduceat(t1, starts)
            of = np.repeat(np.arange(starts.size), ends - starts)   # window -> its span
        # (spans x switches) in one pass each: a Python loop over the 2 x 128 lines cost ~30 ms
        # per digitizer read
        row_lit = rows_bank.possibly_lit_many(bonded, span0, span1, floor)
        col_lit = cols_bank.possibly_lit_many(np.arange(self.config.cols), span0, span1, floor)
        # candidate (span, row, col) beams, then every window of each span
        rk, ri = np.nonzero(row_lit)
        ck, cc = np.nonzero(col_lit)
        n = span0.size
        nc = np.bincount(ck, minlength=n)
        col_start = np.cumsum(nc) - nc
        rep = nc[rk]
        sk = np.repeat(rk, rep)
        pr = bonded[np.repeat(ri, rep)]
        within = np.arange(sk.size) - np.repeat(np.cumsum(rep) - rep, rep)
        pc = cc[col_start[sk] + within]
        if dwell is None:
            pk = sk
        else:
            per_span = np.bincount(of, minlength=n)           # windows per span
            first_win = np.cumsum(per_span) - per_span
            rep_w = per_span[sk]
            beam = np.repeat(np.arange(sk.size), rep_w)
            pk = first_win[sk][beam] + (np.arange(beam.size) - np.repeat(np.cumsum(rep_w) - rep_w, rep_w))
            pr, pc = pr[beam], pc[beam]
            order = np.argsort(pk, kind="stable")             # window-major, as without dwells
            pk, pr, pc = pk[order], pr[order], pc[order]
        trans = mean_path_transmission(rows_bank, pr, cols_bank, pc, t0[pk], t1[pk])
        keep = trans > floor
        return pk[keep], pr[keep], pc[keep], trans[keep]

    def lit_beams(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, mean path transmission) of beams leaving the chip during [t0, t1]."""
        with self._lock:
            _, r, c, tr = self._beams(np.array([t0_s], float), np.array([t1_s], float))
            return r, c, tr

    def triggers(self, first: int, count: int, capture_s: float) -> TriggerBatch:
        """Triggers ``first .. first+count-1`` of the current run and their lit beams.

        Pure computation from the schedule and the drive log: does not advance the clock.
        """
        with self._lock:
            if self._run is None:
                raise ValueError("fpga: no run has been started (no triggers)")
            total = self._run.schedule.total_triggers
            if first < 0 or count < 0 or first + count > total:
                raise ValueError(
                    f"fpga: triggers {first}..{first + count - 1} outside the run's 0..{total - 1}")
            if not capture_s >= 0 or not math.isfinite(capture_s):
                raise ValueError(f"fpga: capture_s must be finite and >= 0, got {capture_s!r}")
            if count == 0:
                return TriggerBatch.empty(capture_s)
            sched = self._run.schedule
            index = np.arange(first, first + count, dtype=np.int64)
            t = sched.trigger_s(index)
            pixel = (index // sched.triggers_per_pixel).astype(np.int32)
            px = self._run.pattern[pixel]
            bk, br, bc, bt = self._beams(t, t + capture_s, dwell=pixel)
            return TriggerBatch(
                index=index, t_s=t, pixel_index=pixel, row=px[:, 0].astype(np.int16),
                col=px[:, 1].astype(np.int16), beam_trigger=bk.astype(np.int32),
                beam_row=br.astype(np.int16), beam_col=bc.astype(np.int16),
                beam_transmission=bt.astype(np.float64), capture_s=float(capture_s))

    # --- transports ---------------------------------------------------------------------------
    def open_pipe(self, line: SerialLineNoise | None = None) -> SimSerial:
        return SimSerial(self, line)

    def serve_pty(self, line: SerialLineNoise | None = None) -> PtyServer:
        return PtyServer(self, line)


class SimSerial:
    """In-memory serial-like channel to an :class:`FpgaSim` (write -> device -> read buffer).

    ``read`` returns what is buffered, possibly nothing, as a real port does when its read
    timeout expires, so a driver's timeout logic runs without any wall-clock wait.
    """

    def __init__(self, sim: FpgaSim, line: SerialLineNoise | None = None) -> None:
        self.sim = sim
        self.line = line
        self.timeout: float | None = 0.0
        self.is_open = True
        self._rx = bytearray()

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise OSError("SimSerial is closed")
        data = bytes(data)
        if self.line is None:
            self._rx += self.sim.feed(data)
        else:
            self._rx += self.line.apply(self.sim.feed(self.line.apply(data)))
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False


class PtyServer:
    """Serve an :class:`FpgaSim` on a pseudo-terminal; open :attr:`path` like a serial device.

    A thread reads the master side, feeds the simulator and writes its answers back. The slave
    fd stays open here so the pty does not hang up when the driver closes and reopens it.
    ``line`` (optional) corrupts the bytes of both directions. :meth:`close` closes the master:
    the device is gone, and host reads/writes on the slave fail (EIO) from then on.
    """

    def __init__(self, sim: FpgaSim, line: SerialLineNoise | None = None) -> None:
        self.sim = sim
        self.line = line
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._closed = False
        self._thread = threading.Thread(target=self._serve, name=f"fpga-pty {self.path}",
                                        daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while True:
            ready, _, _ = select.select([self._master, self._wake_r], [], [])
            if self._wake_r in ready:
                return
            try:
                data = os.read(self._master, 65536)
            except OSError:
                return
            if not data:
                return
            line = self.line
            if line is not None:
                data = line.apply(data)
            resp = self.sim.feed(data) if data else b""
            if line is not None:
                resp = line.apply(resp)
            view = memoryview(resp)
            while view:
                n = os.write(self._master, view)
                view = view[n:]

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        os.write(self._wake_w, b"x")
        self._thread.join(timeout=5)
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            os.close(fd)

    def __enter__(self) -> PtyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["FpgaConfig", "FpgaSim", "HV583", "PtyServer", "SimSerial", "default_bonded_rows"]
