"""Driver for the laser / TEC / HV controller over Modbus TCP (pymodbus sync client).

Typed methods over the register map in drivers/controller/protocol.py (wire format and golden
bytes: docs/protocols/controller.md). The controller powers the DFB laser (Optilab DFB-1550,
§4.4.1) with its TEC, and the MEMS HV of the FPSA (50 V for the 128x128 array, §4.3; pull-in 32 V /
release 29 V for the 20x20 array, §4.2.6), gated by a safety interlock.

Guarantees:
- Setpoints are checked against the driver's own ``Limits`` BEFORE anything is sent
  (``LimitError`` naming quantity, value and range). The device checks its hardware limits again
  and answers exception 3, mapped to ``DeviceRefused`` naming register and value.
- Every request is tried at most ``retries + 1`` times; a reply that never comes ends in
  ``DeviceTimeout("controller", operation)``. Between attempts the TCP connection is reopened so a
  late reply to an abandoned request cannot be taken for the answer to the next one. All writes
  of this map are idempotent (setpoints, enables, CLEAR_FAULTS), so retrying a write is safe.
- Modbus exception responses become typed errors (errors.modbus_exception).
- Reconnect: a refused or dropped TCP connection (``ConnectionException``) is retried within the
  same bounded budget, the client reconnecting on the next request (pymodbus' sync client connects
  lazily), with ``backoff_s * 2**k`` between attempts through the injected ``sleep``; only then
  ``DeviceUnreachable`` naming host, port and operation. ``reconnect()`` forces a fresh connection.
- Thread-safe per request: one lock is held for each Modbus request and its reply (and the
  reconnect after a lost one), never across a sequence or a backoff, so a safety monitor on another
  thread waits at most for the one request in flight, even while ``bring_up`` waits for readbacks.
- ``bring_up``/``bring_down`` command AND read back; waiting uses the injected
  ``SettleCheck.sleep`` (``time.sleep`` in the lab, ``VirtualClock.advance`` on the bench), so this
  module never decides what time is.

Sync ``ModbusTcpClient`` was chosen because the one scan worker that owns the hardware is a plain
thread; an asyncio client would force a loop onto every caller. The power sequences and their
``SettleCheck`` are ``drivers/controller/sequences.py`` (re-exported here).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from urllib.parse import SplitResult, urlsplit

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException
from pymodbus.pdu import ModbusPDU

from drivers.controller import protocol as p
from drivers.controller.errors import (
    DEVICE,
    ConfigError,
    DeviceFailure,
    DeviceFaulted,
    DeviceTimeout,
    DeviceUnreachable,
    InterlockOpen,
    bad_value,
    modbus_exception,
)
from drivers.controller.sequences import PowerSequences, SettleCheck
from drivers.retry import RetryPolicy

log = logging.getLogger(__name__)

#: Modbus exceptions that ask the client to come back later (5 ACKNOWLEDGE, 6 SERVER DEVICE BUSY)
_TRANSIENT_CODES = frozenset({5, 6})


class LaserHvController:
    """Laser / TEC / HV controller on Modbus TCP (``bring_up``/``bring_down``:
    :class:`~drivers.controller.sequences.PowerSequences` over this driver's registers)."""

    def __init__(
        self,
        host: str,
        port: int = 502,
        *,
        device_id: int = 1,
        timeout_s: float = 0.5,
        retries: int = 2,
        limits: p.Limits,
        settle_check: SettleCheck | None = None,
        sleep: Callable[[float], object] | None = None,
        backoff_s: float = 0.02,
        busy_retries: int = 0,
    ) -> None:
        if not isinstance(limits, p.Limits):
            raise ConfigError(f"{DEVICE}: limits must be a protocol.Limits, got {limits!r}")
        if not (isinstance(retries, int) and retries >= 0):
            raise ConfigError(f"{DEVICE}: retries must be an int >= 0, got {retries!r}")
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ConfigError(f"{DEVICE}: timeout_s must be > 0, got {timeout_s!r}")
        if not (isinstance(device_id, int) and 0 <= device_id <= 255):
            raise ConfigError(f"{DEVICE}: device_id must be in 0..255, got {device_id!r}")
        self.host = host
        self.port = int(port)
        self.device_id = device_id
        self.timeout_s = float(timeout_s)
        self.retries = retries
        self.limits = limits
        self.settle_check = settle_check
        self._sequences = PowerSequences(self)
        import time as _time
        self._sleep = sleep if sleep is not None else _time.sleep
        self.backoff_s = float(backoff_s)
        if not (isinstance(busy_retries, int) and busy_retries >= 0):
            raise ConfigError(f"{DEVICE}: busy_retries must be an int >= 0, got {busy_retries!r}")
        self.busy_retries = busy_retries
        # two budgets: requests that got no answer (re-sent at once after a timeout, after the
        # backoff when the connection was refused), and "busy, come back later" answers
        self._no_reply = RetryPolicy.retries(retries, self.backoff_s, self._sleep)
        self._busy = RetryPolicy.retries(busy_retries, self.backoff_s, self._sleep)
        self.reconnect_count = 0    # connections re-established after a loss
        self._lost = False
        #: bytes handed to the socket so far (tests use it to prove that a refused write sent nothing)
        self.bytes_sent = 0
        # one request/reply at a time on the shared TCP connection (scan thread + safety watch)
        self._io_lock = threading.Lock()
        # pymodbus' own retries are off: retries are counted and bounded here, with a reconnect
        # between attempts.
        self._client = ModbusTcpClient(
            host, port=self.port, timeout=self.timeout_s, retries=0, trace_packet=self._trace_packet,
        )

    @classmethod
    def from_url(cls, url: str, **kwargs: object) -> LaserHvController:
        """``modbus+tcp://host[:port]`` (port 502 by default), as the other drivers' ``from_url``;
        a URL of any other form is a ConfigError naming it. Keywords go to the constructor."""
        parts: SplitResult | None = urlsplit(url) if isinstance(url, str) else None
        try:
            port = parts.port if parts is not None else None
        except ValueError:
            port, parts = None, None
        if parts is None or parts.scheme != "modbus+tcp" or not parts.hostname or parts.path not in ("", "/"):
            raise ConfigError(f"{DEVICE}: controller URL must be modbus+tcp://host[:port], got {url!r}")
        return cls(parts.hostname, 502 if port is None else port, **kwargs)  # type: ignore[arg-type]

    # -- lifecycle --------------------------------------------------------------------------
    def close(self) -> None:
        with self._io_lock:
            self._client.close()

    def reconnect(self) -> None:
        """Drop the TCP connection and open a new one (DeviceUnreachable if refused)."""
        with self._io_lock:
            self._client.close()
            if not self._client.connect():
                raise DeviceUnreachable(DEVICE, self.host, self.port, "reconnect")
            self.reconnect_count += 1

    def __enter__(self) -> LaserHvController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            self.bytes_sent += len(data)
        return data

    # -- transport core ---------------------------------------------------------------------
    def _call(self, operation: str, register: p.Register, value: object,
              request: Callable[..., ModbusPDU], *args: object, **kwargs: object) -> ModbusPDU:
        attempts = 0   # attempts that failed for want of an answer (timeout / no connection)
        busy = 0       # "come back later" exception answers
        unreachable: ConnectionException | None = None
        try:
            while attempts < self._no_reply.attempts:
                if unreachable is not None:
                    self._no_reply.sleep(self._no_reply.delay_s(attempts))
                try:
                    with self._io_lock:
                        try:
                            rsp = request(*args, device_id=self.device_id, **kwargs)
                        except (ConnectionException, ModbusIOException):
                            self._client.close()  # drop any late reply before the next attempt
                            raise
                except ConnectionException as exc:
                    # the next request reconnects (lazy connect); bounded by the same retry budget
                    unreachable = exc
                    self._lost = True
                    attempts += 1
                    continue
                except ModbusIOException:
                    attempts += 1
                    log.warning("%s: no reply to %s (attempt %d/%d)", DEVICE, operation, attempts,
                                self.retries + 1)
                    continue
                if rsp.isError():
                    code = getattr(rsp, "exception_code", None)
                    if not isinstance(code, int):
                        raise bad_value(f"{operation} reply", rsp, "error response without an exception code")
                    if code in _TRANSIENT_CODES and busy + 1 < self._busy.attempts:
                        # ACKNOWLEDGE / SERVER DEVICE BUSY mean "try again later": back off and repeat
                        busy += 1
                        delay = self._busy.delay_s(busy)
                        log.warning("%s: %s answered Modbus exception %d; retry %d/%d in %.3g s", DEVICE,
                                    operation, code, busy, self.busy_retries, delay)
                        self._busy.sleep(delay)
                        continue
                    raise modbus_exception(operation, register.name, value, code)
                if self._lost:
                    self._lost = False
                    self.reconnect_count += 1
                return rsp
            if unreachable is not None:
                raise DeviceUnreachable(DEVICE, self.host, self.port, operation) from unreachable
            raise DeviceTimeout(DEVICE, operation, attempts=attempts)
        finally:
            # a kept exception's traceback holds this frame (see DigitizerDriver._guard)
            unreachable = None


    def _read_words(self, operation: str, register: p.Register, count: int) -> list[int]:
        fn = (self._client.read_input_registers if register.table is p.Table.INPUT
              else self._client.read_holding_registers)
        rsp = self._call(operation, register, None, fn, register.address, count=count)
        words = list(rsp.registers)
        if len(words) != count:
            raise bad_value(f"{register.name} reply length", len(words), f"expected {count} words")
        return words

    def _read_bits(self, operation: str, register: p.Register, count: int) -> list[bool]:
        fn = (self._client.read_coils if register.table is p.Table.COIL
              else self._client.read_discrete_inputs)
        rsp = self._call(operation, register, None, fn, register.address, count=count)
        bits = list(rsp.bits)
        if len(bits) < count:
            raise bad_value(f"{register.name} reply length", len(bits), f"expected {count} bits")
        return [bool(b) for b in bits[:count]]

    def _read(self, operation: str, register: p.Register) -> float | int | bool | str:
        if register.kind is p.Kind.BOOL:
            return self._read_bits(operation, register, 1)[0]
        return p.decode_value(register, self._read_words(operation, register, register.words))

    def _write_setpoint(self, operation: str, register: p.Register, value: float) -> None:
        v = self.limits.check(register, value)  # LimitError before anything is sent
        (word,) = p.encode_value(register, v)
        self._call(operation, register, v, self._client.write_register, register.address, word)

    def _write_coil(self, operation: str, register: p.Register, on: bool) -> None:
        if not isinstance(on, bool):
            raise TypeError(f"{DEVICE}: {operation} expects a bool, got {on!r}")
        self._call(operation, register, on, self._client.write_coil, register.address, on)

    # -- identity / status ------------------------------------------------------------------
    def identify(self) -> p.Identity:
        """Model, firmware and map version; a PayloadError (ProtocolError) if the device serves another map."""
        ident = p.decode_identity(self._read_words("identify", p.MODEL, p.IDENTITY_BLOCK[1]))
        if ident.map_version != p.MAP_VERSION:
            raise bad_value("MAP_VERSION", ident.map_version,
                                f"driver understands register map version {p.MAP_VERSION}")
        return ident

    def status(self) -> p.Status:
        """Readbacks, faults, uptime and heartbeat in one request."""
        return p.decode_status(self._read_words("read status", p.LASER_CURRENT, p.STATUS_BLOCK[1]))

    def flags(self) -> p.Flags:
        """Interlock, output states, fault summary and TEC-settled in one request."""
        return p.decode_flags(self._read_bits("read flags", p.INTERLOCK_CLOSED, p.FLAGS_BLOCK[1]))

    def uptime_s(self) -> float:
        return int(self._read("read uptime", p.UPTIME_MS)) / 1000.0

    def heartbeat(self) -> int:
        return int(self._read("read heartbeat", p.HEARTBEAT))

    # -- power sequences (drivers.controller.sequences) --------------------------------------
    def bring_up(self, current_ma: float, hv_v: float, *, settle_check: SettleCheck | None = None) -> p.Status:
        """TEC settled -> HV on -> laser on, each read back (:meth:`PowerSequences.bring_up`)."""
        return self._sequences.bring_up(current_ma, hv_v, settle_check=settle_check)

    def bring_down(self, *, settle_check: SettleCheck | None = None) -> p.Status:
        """Laser off, then HV off, both read back to 0 (:meth:`PowerSequences.bring_down`)."""
        return self._sequences.bring_down(settle_check=settle_check)

    # -- laser ------------------------------------------------------------------------------
    def laser_enable(self, on: bool) -> None:
        self._enable("laser enable", p.LASER_ENABLE, on)

    def laser_is_on(self) -> bool:
        return bool(self._read("read laser on", p.LASER_ON))

    def set_laser_current_ma(self, current_ma: float) -> None:
        self._write_setpoint("set laser current", p.LASER_CURRENT_SETPOINT, current_ma)

    def laser_current_setpoint_ma(self) -> float:
        return float(self._read("read laser current setpoint", p.LASER_CURRENT_SETPOINT))

    def laser_current_ma(self) -> float:
        """Measured laser current (readback)."""
        return float(self._read("read laser current", p.LASER_CURRENT))

    # -- TEC --------------------------------------------------------------------------------
    def set_tec_c(self, temperature_c: float) -> None:
        self._write_setpoint("set TEC temperature", p.TEC_SETPOINT, temperature_c)

    def tec_setpoint_c(self) -> float:
        return float(self._read("read TEC setpoint", p.TEC_SETPOINT))

    def tec_c(self) -> float:
        """Measured laser temperature (readback)."""
        return float(self._read("read TEC temperature", p.TEC_TEMPERATURE))

    # -- HV ---------------------------------------------------------------------------------
    def hv_enable(self, on: bool) -> None:
        self._enable("HV enable", p.HV_ENABLE, on)

    def hv_is_on(self) -> bool:
        return bool(self._read("read HV on", p.HV_ON))

    def set_hv_v(self, voltage_v: float) -> None:
        self._write_setpoint("set HV voltage", p.HV_SETPOINT, voltage_v)

    def hv_setpoint_v(self) -> float:
        return float(self._read("read HV setpoint", p.HV_SETPOINT))

    def set_hv_hold_v(self, voltage_v: float) -> None:
        """Hold drive: lines pull in at the HV, then hold at ``voltage_v`` (0 = hold at the HV).
        Pick it above the switches' release voltage and below their pull-in voltage."""
        self._write_setpoint("set HV hold voltage", p.HV_HOLD_SETPOINT, voltage_v)

    def hv_hold_setpoint_v(self) -> float:
        return float(self._read("read HV hold setpoint", p.HV_HOLD_SETPOINT))

    def hv_v(self) -> float:
        """Measured HV output voltage (readback)."""
        return float(self._read("read HV voltage", p.HV_VOLTAGE))

    # -- interlock / faults -----------------------------------------------------------------
    def interlock_closed(self) -> bool:
        return bool(self._read("read interlock", p.INTERLOCK_CLOSED))

    def faults(self) -> frozenset[p.Fault]:
        return p.decode_faults(int(self._read("read faults", p.FAULTS)))

    def clear_faults(self) -> frozenset[p.Fault]:
        """Clear latched faults whose cause is gone; returns the faults still latched."""
        self._call("clear faults", p.COMMAND, p.Command.CLEAR_FAULTS.name, self._client.write_register,
                   p.COMMAND.address, int(p.Command.CLEAR_FAULTS))
        return self.faults()

    def _enable(self, operation: str, register: p.Register, on: bool) -> None:
        try:
            self._write_coil(operation, register, on)
        except DeviceFailure as exc:
            # The device refuses an enable (exception 4) when the interlock is open or a fault is
            # latched; say which.
            if not self.interlock_closed():
                raise InterlockOpen(operation) from exc
            latched = self.faults()
            if latched:
                raise DeviceFaulted(operation, latched) from exc
            raise


__all__ = ["LaserHvController", "SettleCheck"]
