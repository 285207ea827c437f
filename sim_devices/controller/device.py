"""Simulated laser / TEC / HV controller: a pymodbus TCP server on 127.0.0.1 with device logic.

Byte-level peer of drivers/controller/driver.py (register map in drivers/controller/protocol.py,
wire format in docs/protocols/controller.md). What it models:

- DFB laser injection current (§4.4.1, Fig. 4-29), TEC-held laser temperature and the MEMS HV
  supply of the FPSA (50 V actuation for 128x128, §4.3; pull-in 32 V / release 29 V for 20x20,
  §4.2.6). Readbacks follow their targets with first-order lags on the shared VirtualClock
  (x -> target + (x - target) * exp(-dt / tau)); nothing here reads the wall clock or sleeps.
- Hardware limits enforced again in the device: an out-of-range setpoint write is refused with
  Modbus exception 3 (ILLEGAL DATA VALUE) and changes nothing (multi-register writes are atomic).
- Interlock: opening it turns laser and HV off at once (outputs crowbarred to 0, not lagged) and
  latches Fault.INTERLOCK_OPEN. Enabling laser or HV while the interlock is open or any fault is
  latched is REFUSED with exception 4 (SERVER DEVICE FAILURE); the coil keeps reading 0.
  COMMAND=CLEAR_FAULTS clears latched faults whose cause is gone (INTERLOCK_OPEN stays while open).
- Fault injection for tests/bench: ``inject_exception(code, n)`` answers the next n requests with
  that exception, ``inject_timeout(n)`` swallows the next n responses (the request is still
  executed, like a reply lost on the wire); ``n=None`` means until ``clear_injected()``.
  ``inject_fault(fault)`` latches a fault and trips the outputs; ``set_fault_cause(fault, True)``
  also keeps its cause present, so CLEAR_FAULTS cannot clear it until the cause goes away
  (``set_fault_cause(fault, False)``), like the interlock loop for INTERLOCK_OPEN.
- TEC: the loop holds its thermistor at the set point and TEC_TEMPERATURE reads that thermistor; the
  laser chip's TRUE temperature (``laser_temperature_c()``, what the bench's laser model uses) adds a
  slow drift (``tec_drift``: sim_devices.world.tec.TecDrift) and an injected step (``tec_offset_c``,
  fault ``tec_offset``) that the readback cannot show.

The device logic (state, lags, limits, interlock, faults) is ``sim_devices.controller.model``; this
module serves it over Modbus TCP and injects the protocol-level faults. Start/stop from a thread
(``start()``/``stop()``, or ``with ControllerSim(...) as sim``) or from a running asyncio loop
(``await start_async()``/``await stop_async()``). Port 0 binds a free port, reported by ``.port``.
"""

from __future__ import annotations

import asyncio
import threading

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ModbusPDU
from pymodbus.server import ModbusBaseServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.controller import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.controller.model import (
    ControllerModel,
    ControllerSpec,
    ControllerState,
    Dynamics,
    _bits_to_words,
)

_READ_FC_TABLE = {1: p.Table.COIL, 2: p.Table.DISCRETE_INPUT, 3: p.Table.HOLDING, 4: p.Table.INPUT}
_WRITE_FC_TABLE = {5: p.Table.COIL, 15: p.Table.COIL, 6: p.Table.HOLDING, 16: p.Table.HOLDING,
                   22: p.Table.HOLDING, 23: p.Table.HOLDING}


class ControllerSim:
    """The simulated controller served over Modbus TCP."""

    def __init__(
        self,
        clock: VirtualClock | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        device_id: int = 1,
        spec: ControllerSpec | None = None,
        tec_drift=None,
    ) -> None:
        """``spec`` and ``tec_drift``: the device simulated (:class:`ControllerModel`)."""
        self.clock = clock if clock is not None else VirtualClock()
        self.model = ControllerModel(self.clock, spec=spec, tec_drift=tec_drift)
        self.host = host
        self.device_id = device_id
        self._requested_port = port
        self.port: int | None = None
        self._inject_lock = threading.Lock()
        self._pending_exceptions: list[int] = []
        self._pending_timeouts = 0
        self._sticky_exception: int | None = None  # every request, until clear_injected()
        self._sticky_timeout = False
        self._current_exception: int | None = None
        self.requests_received = 0
        self.responses_dropped = 0
        self._server: ModbusTcpServer | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None

    # -- bench-facing state -----------------------------------------------------------------
    @property
    def state(self) -> ControllerState:
        return self.model.state

    def set_interlock(self, closed: bool) -> None:
        self.model.set_interlock(closed)

    def inject_fault(self, fault: p.Fault) -> None:
        self.model.inject_fault(fault)

    def set_fault_cause(self, fault: p.Fault, present: bool) -> None:
        self.model.set_fault_cause(fault, present)

    def inject_exception(self, code: int, n: int | None = 1) -> None:
        """Answer the next ``n`` requests (``None``: all until :meth:`clear_injected`) with Modbus
        exception ``code`` (nothing executed)."""
        ExcCodes(code)  # ValueError for a code Modbus does not define
        with self._inject_lock:
            if n is None:
                self._sticky_exception = int(code)
            else:
                self._pending_exceptions.extend([int(code)] * n)

    def inject_timeout(self, n: int | None = 1) -> None:
        """Swallow the responses to the next ``n`` requests (``None``: all until
        :meth:`clear_injected`); the requests still execute."""
        with self._inject_lock:
            if n is None:
                self._sticky_timeout = True
            else:
                self._pending_timeouts += int(n)

    def clear_injected(self, what: str | None = None) -> int:
        """Drop pending injected ``"exception"`` / ``"timeout"`` faults (both if None); returns
        how many requests' worth were pending (a persistent one counts 1)."""
        if what not in (None, "exception", "timeout"):
            raise ValueError(f"controller: clear_injected what must be 'exception' or 'timeout', "
                             f"got {what!r}")
        n = 0
        with self._inject_lock:
            if what in (None, "exception"):
                n += len(self._pending_exceptions) + (self._sticky_exception is not None)
                self._pending_exceptions.clear()
                self._sticky_exception = None
            if what in (None, "timeout"):
                n += self._pending_timeouts + int(self._sticky_timeout)
                self._pending_timeouts = 0
                self._sticky_timeout = False
        return n

    # -- pymodbus hooks ---------------------------------------------------------------------
    async def _action(self, function_code: int, start_address: int, address: int, count: int,
                      registers: list[int], set_values: list[int] | list[bool] | None) -> ExcCodes | None:
        if self._current_exception is not None:
            return ExcCodes(self._current_exception)
        if set_values is not None:
            table = _WRITE_FC_TABLE.get(function_code)
            if table is None:
                return ExcCodes.ILLEGAL_FUNCTION
            code = self.model.write(table, address, set_values)
            if code is not None:
                return ExcCodes(int(code))
        else:
            table = _READ_FC_TABLE.get(function_code) or _WRITE_FC_TABLE[function_code]
        # Refresh pymodbus' register block from the model so the read (or the write's echo)
        # reflects device logic; the block starts at address 0 (see _build_device).
        img = self.model.image(table)
        words = _bits_to_words(img) if table in (p.Table.COIL, p.Table.DISCRETE_INPUT) else list(img)
        registers[0:len(words)] = words
        return None

    def _trace_pdu(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU:
        if not sending:
            self.requests_received += 1
            self.model.heartbeat += 1
            # Decide per request (not per datastore call: a write calls the action twice).
            with self._inject_lock:
                if self._pending_exceptions:
                    self._current_exception = self._pending_exceptions.pop(0)
                else:
                    self._current_exception = self._sticky_exception
        return pdu

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            with self._inject_lock:
                if self._sticky_timeout:
                    self.responses_dropped += 1
                    return b""
                if self._pending_timeouts > 0:
                    self._pending_timeouts -= 1
                    self.responses_dropped += 1
                    return b""
        return data

    def _build_device(self) -> SimDevice:
        def bits(table: p.Table) -> list[SimData]:
            return [SimData(0, values=[False] * p.table_size(table), datatype=DataType.BITS)]

        def regs(table: p.Table) -> list[SimData]:
            return [SimData(0, values=[0] * p.table_size(table), datatype=DataType.REGISTERS)]

        return SimDevice(
            self.device_id,
            simdata=(bits(p.Table.COIL), bits(p.Table.DISCRETE_INPUT),
                     regs(p.Table.HOLDING), regs(p.Table.INPUT)),
            action=self._action,
        )

    # -- lifecycle --------------------------------------------------------------------------
    async def start_async(self) -> int:
        """Start serving inside the running loop; returns the bound port."""
        if self._server is not None:
            raise RuntimeError("controller sim already started")
        server = ModbusTcpServer(
            self._build_device(),
            address=(self.host, self._requested_port),
            trace_packet=self._trace_packet,
            trace_pdu=self._trace_pdu,
        )
        await server.serve_forever(background=True)
        self._server = server
        # pymodbus types its transport as a BaseTransport; serving TCP, it is the asyncio.Server
        self.port = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]
        return self.port

    async def stop_async(self) -> None:
        if self._server is None:
            return
        server, self._server = self._server, None
        await server.shutdown()
        if ModbusBaseServer.active_server is server:  # pymodbus keeps the last server alive
            ModbusBaseServer.active_server = None

    def start(self, timeout_s: float = 5.0) -> int:
        """Run the server on its own thread + event loop; returns the bound port."""
        if self._thread is not None:
            raise RuntimeError("controller sim already started")
        ready = threading.Event()
        failure: list[BaseException] = []

        async def main() -> None:
            self._loop = asyncio.get_running_loop()
            self._stop_event = asyncio.Event()
            try:
                await self.start_async()
            except BaseException as exc:  # reported to the starting thread
                failure.append(exc)
                ready.set()
                return
            ready.set()
            await self._stop_event.wait()
            await self.stop_async()

        self._thread = threading.Thread(target=asyncio.run, args=(main(),),
                                        name=f"controller-sim-{self.host}", daemon=True)
        self._thread.start()
        if not ready.wait(timeout_s):
            raise RuntimeError("controller sim did not start in time")
        if failure:
            self._thread.join()
            self._thread = None
            raise RuntimeError(f"controller sim failed to start on {self.host}:{self._requested_port}") \
                from failure[0]
        assert self.port is not None
        return self.port

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._thread is None:
            return
        if self._loop is not None and self._stop_event is not None:
            self._loop.call_soon_threadsafe(self._stop_event.set)
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise RuntimeError("controller sim thread did not stop")
        self._thread = None
        self._loop = None

    def __enter__(self) -> ControllerSim:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


__all__ = ["ControllerModel", "ControllerSim", "ControllerState", "Dynamics"]
