"""The FPSA board's firmware: its state machine and what each wire command of docs/protocols/fpsa.md
does to the board (§4.3.3 and Fig. 4-22; the run's line changes follow the pixel schedule of
``sim_devices.fpsa.triggers``).

:class:`Firmware` is held by :class:`sim_devices.fpsa.device.FpgaSim` as ``fpga.firmware`` and holds
the board it commands (:class:`~sim_devices.fpsa.board.FpsaBoard`: HV583 registers, drive log). It
owns the firmware's state (state, fault flags, timing, the pattern upload, the verified pattern, the
run), maps a decoded frame to its handler, enforces the state machine (FAULT until RESET;
configuration only in IDLE/DONE/ARMED; START only when ARMED), validates payloads (NAK codes of the
protocol), uploads and verifies patterns chunk by chunk, and at START logs every HV line change of
the whole run in closed form (cut short later by STOP/RESET). The byte interface, its retry cache
and the transports stay in ``sim_devices.fpsa.device``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from drivers.fpsa import protocol as p
from drivers.errors import LengthError, PayloadError
from sim_devices.fpsa.board import FpsaBoard
from sim_devices.fpsa.drive_log import COL, ROW, compact
from sim_devices.fpsa.hv583 import HV583
from sim_devices.fpsa.hv_drive import HOLD_BOOST_S
from sim_devices.fpsa.triggers import PixelSchedule

# Finished runs whose trigger count the board remembers (a digitizer armed before them numbers its
# segments across them; a stream arms once for many frames, each a run)
RETIRED_RUNS_KEPT = 64


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


class Firmware:
    """The FPGA firmware's state machine and command handlers over one board."""

    def __init__(self, board: FpsaBoard) -> None:
        self.board = board
        self.config = board.config
        self.state = p.State.FAULT
        self.faults = p.FaultFlag.HV_UNINITIALIZED
        self.timing = p.DEFAULT_TIMING
        self._upload: _Upload | None = None
        self.pattern: np.ndarray | None = None  # verified
        self.run: _Run | None = None
        self._run_slot = -1
        # triggers of the runs before the current one (since power-up), and the last runs' schedules
        # with their first trigger's number: what a digitizer armed across runs counts
        self.trigger_base = 0
        self.retired: list[tuple[PixelSchedule, int]] = []

    def power_up(self, t_s: float) -> None:
        """Power-up: FAULT with HV_UNINITIALIZED (and MULTI_ROW when the random registers drive
        several bonded rows) until the host sends RESET."""
        self.state = p.State.FAULT
        self.faults = p.FaultFlag.HV_UNINITIALIZED
        if self.board.power_up(t_s):
            self.faults |= p.FaultFlag.MULTI_ROW
        self.timing = p.DEFAULT_TIMING
        self._upload = None
        self.pattern = None
        self.run = None
        self._run_slot = -1

    def sync(self, now: float) -> None:
        """Bring the firmware state up to ``now`` (a run that ended becomes DONE)."""
        run = self.run
        if self.state == p.State.RUNNING and run is not None and now >= run.schedule.end_s:
            self.state = p.State.DONE
            self.board.clear_registers()

    def cut_run(self, t_s: float) -> None:
        """STOP/RESET during a run: drop run events after ``t_s`` and switch its lines off."""
        run = self.run
        if run is None or self.state != p.State.RUNNING or t_s >= run.schedule.end_s:
            return
        sched = run.schedule
        # the run's events are one slot of the log: keep only what happened before the cut
        ev, k = self.board.events, self._run_slot
        keep = ev.t[k] < t_s
        ev.kind[k], ev.line[k], ev.t[k], ev.v[k] = (ev.kind[k][keep], ev.line[k][keep],
                                                    ev.t[k][keep], ev.v[k][keep])
        # whatever is still high just before the cut goes off at the cut (blanking)
        rows_high, cols_high = self.board.lines_high_before(t_s)
        for kind, high in ((ROW, rows_high), (COL, cols_high)):
            idx = np.flatnonzero(high)
            if idx.size:
                ev.add(kind, idx, t_s, 0.0)
        self.run = _Run(run.pattern, dataclasses.replace(sched, cut_s=t_s))
        self.board.clear_registers()
        self.board.touch()

    def status(self, now: float) -> p.Status:
        """What STATUS reports at ``now`` (clears LINK_ERRORS like a STATUS read does)."""
        self.sync(now)
        idx = pixels = trig = 0
        if self.run is not None:
            s = self.run.schedule
            idx, pixels, trig = s.pattern_index(now), s.pixels_done(now), s.triggers_before(now)
        st = p.Status(self.state, self.faults, idx, pixels, trig)
        self.faults &= ~p.FaultFlag.LINK_ERRORS
        return st

    def execute(self, frame: p.Frame, now: float) -> bytes:
        """The response to one decoded frame received at ``now`` (an ACK or a NAK)."""
        self.sync(now)
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
        return p.Identity(c.vendor, c.model, c.firmware, c.rows, c.cols, self.board.bonded).pack()

    def _cmd_reset(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        self.cut_run(now)
        # Firmware reset: blank, clock zeros through every register, latch, set polarity,
        # un-blank. Blanking first means the garbage disappears at once, not after 0.8 us.
        for hv in (self.board.hv_rows, self.board.hv_cols):
            hv.blank = True
        self.board.apply_outputs(now)
        for hv in (self.board.hv_rows, self.board.hv_cols):
            hv.shift_in(np.zeros(HV583.N_OUTPUTS, bool))
            hv.latch_enable()
            hv.polarity_inverted = False
            hv.blank = False
        self.board.apply_outputs(now + HV583.refresh_s())
        self.state = p.State.IDLE
        self.faults = p.FaultFlag.NONE
        self.timing = p.DEFAULT_TIMING
        self._upload = None
        self.pattern = None
        self._retire_run()
        self.run = None
        return b""

    def _check_pixel(self, row: int, col: int, index: int | None) -> None:
        if not (0 <= row < self.config.rows and 0 <= col < self.config.cols):
            raise _Nak(p.NakCode.OUT_OF_RANGE, index)
        if not self.board.bonded_mask[row]:
            raise _Nak(p.NakCode.BAD_ROW_UNBONDED, index)

    def _cmd_set_pixel(self, payload: bytes, now: float) -> bytes:
        row, col = p.decode_set_pixel(payload)
        self._require_config_state()
        self._check_pixel(row, col, None)
        self.board.load_lines(now, row, col)
        self.state = p.State.IDLE
        return b""

    def _cmd_clear(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        self._require_config_state()
        self.board.load_lines(now, None, None)
        self.state = p.State.IDLE
        return b""

    def _cmd_pattern_begin(self, payload: bytes, now: float) -> bytes:
        total, crc = p.decode_pattern_begin(payload)
        self._require_config_state()
        if not 1 <= total <= self.config.rows * self.config.cols:
            raise _Nak(p.NakCode.OUT_OF_RANGE)
        self._upload = _Upload(total, crc, np.zeros((total, 2), np.uint8), np.zeros(total, bool))
        self.pattern = None
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
        bad_bond = ~bad_range & ~self.board.bonded_mask[np.minimum(r, self.config.rows - 1)]
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
        self.pattern = up.data.copy()
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
        if self.pattern is None:
            raise _Nak(p.NakCode.BAD_STATE)
        self.state = p.State.ARMED
        return b""

    def _cmd_start(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        if self.state != p.State.ARMED or self.pattern is None:
            raise _Nak(p.NakCode.BAD_STATE)
        tm = self.timing
        sched = PixelSchedule(
            run_start_s=now, n_pixels=int(self.pattern.shape[0]), refresh_s=HV583.refresh_s(),
            settle_s=tm.settle_ns * 1e-9, trigger_period_s=tm.trigger_period_ns * 1e-9,
            triggers_per_pixel=tm.triggers_per_pixel, dwell_s=tm.dwell_ns * 1e-9)
        self._retire_run()
        self.run = _Run(self.pattern.copy(), sched)
        self._log_run_events(self.run)
        self.state = p.State.RUNNING
        return b""

    def _retire_run(self) -> None:
        """Count the triggers of the run that ends here (ran out or was stopped) into the board's trigger
        count: a digitizer armed across several runs numbers its segments by that count."""
        run = self.run
        if run is None:
            return
        total = run.schedule.total_triggers
        self.retired.append((run.schedule, self.trigger_base))
        del self.retired[:-RETIRED_RUNS_KEPT]
        self.trigger_base += total

    def _log_run_events(self, run: _Run) -> None:
        """Every line change of the whole run, in closed form (one event list, cut on STOP)."""
        sched = run.schedule
        # what happened long before this run shapes nothing in it: keep the log bounded
        board = self.board
        compact(board.events, board.holds, sched.run_start_s - board.settle_horizon_s, board.stuck.lines())
        rows = run.pattern[:, 0].astype(np.int64)
        cols = run.pattern[:, 1].astype(np.int64)
        n = rows.size
        latch = sched.latch_s(np.arange(n))
        drive = board.supply()
        v = drive.hv_v
        kinds, lines, ts, vs = [], [], [], []

        def add(k, line, t, volts):
            kinds.append(np.full(line.size, k, np.int8))
            lines.append(line)
            ts.append(np.asarray(t, np.float64))
            vs.append(np.full(line.size, volts))

        for k, seq, high in ((ROW, rows, board.row_high), (COL, cols, board.col_high)):
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
        self._run_slot = len(board.events.kind)
        all_k, all_l, all_t, all_v = (np.concatenate(kinds), np.concatenate(lines),
                                      np.concatenate(ts), np.concatenate(vs))
        board.events.add(all_k, all_l, all_t, all_v)
        rising = all_v > 0
        if drive.holds and rising.any():  # holds cut short by a line change are dropped later
            board.holds.add(all_k[rising], all_l[rising], all_t[rising] + HOLD_BOOST_S, drive.hold_v)
        board.row_high[:] = False
        board.col_high[:] = False
        board.touch()

    def _cmd_stop(self, payload: bytes, now: float) -> bytes:
        self._no_payload(payload)
        if self.state == p.State.RUNNING:
            self.cut_run(now)
        else:
            for hv in (self.board.hv_rows, self.board.hv_cols):
                hv.shift_in(np.zeros(HV583.N_OUTPUTS, bool))
                hv.latch_enable()
            self.board.apply_outputs(now + HV583.refresh_s())
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
