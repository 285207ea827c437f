"""Simulated arbitrary waveform generator: a USBTMC/SCPI peer on the simulated USB bus.

§4.4.1: the AWG drives the DFB laser's current with the pre-distorted modulation waveform (§2.2,
Fig. 2-3), one period per external trigger (burst mode) so each chirp lines up with an FPSA pixel.
The bench reads what the instrument would put on its output with ``drive_volts()``, and whether it
is enabled/triggered externally with ``output_on`` / ``trigger_external``.

The device parses the host's bulk-OUT USBTMC stream with the shared codec
(drivers/usbtmc.py, drivers/awg/protocol.py), keeps instrument state and a SCPI error queue
(bounded at 32 entries, overflow -> -350 as IEEE-488.2 requires) and queues replies for
REQUEST_DEV_DEP_MSG_IN. Dialect: docs/protocols/awg.md.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from drivers import usbtmc
from drivers.awg import protocol as p
from sim_devices.usb.backend import DeviceSpec, EndpointSpec, SimUsbDevice, usb_timeout

#: instrument limits (those of a typical 16-bit, 1 GS/s AWG)
SAMPLE_RATE_MIN_HZ = 1e3
SAMPLE_RATE_MAX_HZ = 1e9
AMPLITUDE_MIN_V = 1e-3
AMPLITUDE_MAX_V = 5.0
OUTPUT_MAX_V = 5.0           # |offset| + amplitude must stay within the output stage
WAVEFORM_MIN_POINTS = 2
WAVEFORM_MAX_POINTS = 16 * 1024 * 1024
ERROR_QUEUE_LEN = 32

SCPI_ERRORS = {
    -102: "Syntax error",
    -104: "Data type error",
    -108: "Parameter not allowed",
    -109: "Missing parameter",
    -113: "Undefined header",
    -160: "Block data error",
    -222: "Data out of range",
    -350: "Queue overflow",
    -410: "Query INTERRUPTED",
}


class _ScpiError(Exception):
    def __init__(self, code: int, context: str) -> None:
        self.code = code
        self.context = context


def _float_arg(cmd: p.ScpiCommand) -> float:
    if not cmd.args:
        raise _ScpiError(-109, cmd.header)
    if len(cmd.args) > 1:
        raise _ScpiError(-108, cmd.header)
    a = cmd.args[0]
    if isinstance(a, bytes):
        raise _ScpiError(-104, cmd.header)
    try:
        x = float(a)
    except ValueError:
        raise _ScpiError(-104, f"{cmd.header} {a}") from None
    if not np.isfinite(x):
        raise _ScpiError(-222, f"{cmd.header} {a}")
    return x


def _word_arg(cmd: p.ScpiCommand, allowed: dict[str, bool]) -> bool:
    if not cmd.args:
        raise _ScpiError(-109, cmd.header)
    a = cmd.args[0]
    if isinstance(a, bytes) or len(cmd.args) > 1:
        raise _ScpiError(-104, cmd.header)
    try:
        return allowed[a.upper()]
    except KeyError:
        raise _ScpiError(-104, f"{cmd.header} {a}") from None


class SimAwg(SimUsbDevice):
    """State of the simulated AWG plus its USBTMC endpoint handlers."""

    def __init__(self, serial: str = "SIM0001") -> None:
        super().__init__()
        self.spec = DeviceSpec(
            vid=p.AWG_VID, pid=p.AWG_PID, manufacturer="lidard-sim", product="AWG-16",
            serial=serial, interface_class=0xFE, interface_subclass=0x03, interface_protocol=0x01,
            endpoints=(EndpointSpec(p.AWG_EP_OUT), EndpointSpec(p.AWG_EP_IN)),
        )
        self._parser = usbtmc.UsbtmcOutParser()
        self._partial = bytearray()          # message bytes until EOM
        self._pending_in: deque[tuple[int, bytes, bool]] = deque()  # (bTag, chunk, eom)
        self._replies = bytearray()          # query output not yet requested by the host
        self.errors: deque[tuple[int, str]] = deque()
        self._reset_state()

    # ------------------------------------------------------------------ bench-facing state

    def _reset_state(self) -> None:
        self.sample_rate_hz = 1e9
        self.amplitude_v = 1.0
        self.offset_v = 0.0
        self.trigger_external = False
        self.output_on = False
        self.codes = np.zeros(2, dtype=np.int16)

    def drive_volts(self) -> tuple[np.ndarray, float]:
        """One period of the output waveform in volts (float64) and the sample rate in Hz."""
        return p.volts_from_codes(self.codes, self.amplitude_v, self.offset_v), self.sample_rate_hz

    # ------------------------------------------------------------------------- USB

    def handle_bulk_out(self, ep: int, data: memoryview) -> int:
        if ep != p.AWG_EP_OUT:
            return super().handle_bulk_out(ep, data)
        for hdr, payload in self._parser.feed(data):
            if hdr.msg_id == usbtmc.MSG_DEV_DEP_MSG_OUT:
                self._partial += payload
                if hdr.eom:
                    msg = bytes(self._partial)
                    self._partial.clear()
                    self._execute(msg)
            elif self._replies:  # REQUEST_DEV_DEP_MSG_IN with an answer ready
                chunk = bytes(self._replies[:hdr.transfer_size])
                del self._replies[:hdr.transfer_size]
                self._pending_in.append((hdr.btag, chunk, not self._replies))
            # a request with nothing to answer stays unanswered: the host read times out, as on
            # an instrument whose query failed
        return len(data)

    def handle_bulk_in(self, ep: int, buf: memoryview) -> int:
        if ep != p.AWG_EP_IN:
            return super().handle_bulk_in(ep, buf)
        if not self._pending_in:
            # a real USBTMC device NAKs until a request arrives: the host's read times out
            raise usb_timeout("awg bulk-IN without REQUEST_DEV_DEP_MSG_IN")
        btag, chunk, eom = self._pending_in.popleft()
        frame = usbtmc.encode_dev_dep_msg_in(btag, chunk, eom)
        n = min(len(frame), len(buf))
        buf[:n] = frame[:n]
        return n

    def handle_ctrl(self, bm, req, w_value, w_index, data, w_length):
        if bm == usbtmc.REQTYPE_CLASS_INTERFACE_IN and req == usbtmc.REQ_INITIATE_CLEAR:
            self.handle_reset()
            return bytes([usbtmc.STATUS_SUCCESS])
        if bm == usbtmc.REQTYPE_CLASS_INTERFACE_IN and req == usbtmc.REQ_CHECK_CLEAR_STATUS:
            return bytes([usbtmc.STATUS_SUCCESS, 0])
        return super().handle_ctrl(bm, req, w_value, w_index, data, w_length)

    def handle_clear_halt(self, ep: int) -> None:
        self._parser.reset()
        self._partial.clear()

    def handle_reset(self) -> None:
        self._parser.reset()
        self._partial.clear()
        self._pending_in.clear()
        self._replies.clear()

    # ------------------------------------------------------------------------- SCPI

    def _push_error(self, code: int, context: str) -> None:
        text = SCPI_ERRORS.get(code, "Error")
        if context:
            text = f"{text};{context[:60]}"
        if len(self.errors) >= ERROR_QUEUE_LEN - 1:
            # the last slot is reserved for the overflow marker; newer errors are lost
            if not self.errors or self.errors[-1][0] != -350:
                self.errors.append((-350, SCPI_ERRORS[-350]))
            return
        self.errors.append((code, text))

    def _execute(self, message: bytes) -> None:
        if self._replies:
            # a new command while the previous answer is unread discards it (IEEE-488.2 6.3.2.3)
            self._replies.clear()
            self._push_error(-410, "")
        try:
            commands = p.parse_message(message)
        except p.BlockError as exc:
            self._push_error(-160, str(exc))
            return
        except p.AwgProtocolError as exc:
            self._push_error(-102, str(exc))
            return
        answers: list[bytes] = []
        for cmd in commands:
            try:
                reply = self._run(cmd)
            except _ScpiError as exc:
                self._push_error(exc.code, exc.context)
                continue
            if reply is not None:
                answers.append(reply)
        if answers:
            self._replies += b";".join(answers) + b"\n"

    def _run(self, cmd: p.ScpiCommand) -> bytes | None:
        h, q = cmd.header, cmd.query
        if h == "*IDN" and q:
            s = self.spec
            return f"{s.manufacturer},{s.product},{s.serial},1.0".encode()
        if h == "*RST" and not q:
            self._reset_state()
            return None
        if h == "*CLS" and not q:
            self.errors.clear()
            return None
        if h == "*OPC" and q:
            return b"1"
        if h == "SYST:ERR" and q:
            code, text = self.errors.popleft() if self.errors else (0, "No error")
            return p.format_error(code, text)
        if h == "SOUR:FREQ:SAMP":
            if q:
                return repr(self.sample_rate_hz).encode()
            x = _float_arg(cmd)
            if not SAMPLE_RATE_MIN_HZ <= x <= SAMPLE_RATE_MAX_HZ:
                raise _ScpiError(-222, f"SOUR:FREQ:SAMP {x!r}")
            self.sample_rate_hz = x
            return None
        if h == "SOUR:VOLT":
            if q:
                return repr(self.amplitude_v).encode()
            x = _float_arg(cmd)
            if not AMPLITUDE_MIN_V <= x <= AMPLITUDE_MAX_V or abs(self.offset_v) + x > OUTPUT_MAX_V:
                raise _ScpiError(-222, f"SOUR:VOLT {x!r}")
            self.amplitude_v = x
            return None
        if h == "SOUR:VOLT:OFFS":
            if q:
                return repr(self.offset_v).encode()
            x = _float_arg(cmd)
            if abs(x) + self.amplitude_v > OUTPUT_MAX_V:
                raise _ScpiError(-222, f"SOUR:VOLT:OFFS {x!r}")
            self.offset_v = x
            return None
        if h == "SOUR:DATA:ARB" and not q:
            if len(cmd.args) != 1 or not isinstance(cmd.args[0], bytes):
                raise _ScpiError(-104 if cmd.args else -109, "SOUR:DATA:ARB needs a #-block")
            payload = cmd.args[0]
            if len(payload) % 2:
                raise _ScpiError(-160, "SOUR:DATA:ARB odd byte count")
            npts = len(payload) // 2
            if not WAVEFORM_MIN_POINTS <= npts <= WAVEFORM_MAX_POINTS:
                raise _ScpiError(-222, f"SOUR:DATA:ARB {npts} points")
            self.codes = p.decode_codes(payload)
            return None
        if h == "SOUR:DATA:ARB:POIN" and q:
            return str(self.codes.size).encode()
        if h == "TRIG:SOUR":
            if q:
                return b"EXT" if self.trigger_external else b"IMM"
            self.trigger_external = _word_arg(cmd, {"EXT": True, "EXTERNAL": True,
                                                    "IMM": False, "IMMEDIATE": False})
            return None
        if h == "OUTP":
            if q:
                return b"1" if self.output_on else b"0"
            self.output_on = _word_arg(cmd, {"ON": True, "1": True, "OFF": False, "0": False})
            return None
        raise _ScpiError(-113, h + ("?" if q else ""))
