"""The register map of the laser / TEC / HV controller (Modbus TCP; docs/protocols/controller.md):
the four tables, every register's address, kind, unit and LSB, the blocks the driver reads in one
request, and the command, fault and Modbus exception codes (§4.4.1, Fig. 4-29; §4.3; §4.2.6).

PURE, part of the codec ``drivers.controller.protocol`` (which re-exports every name here and adds
the scaling, limits and decoded blocks). Addresses are 0-based PDU addresses.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


#: Version of this register map, served in input register MAP_VERSION so a driver can refuse a
#: device whose map it does not understand.
MAP_VERSION = 1


class Table(enum.Enum):
    """The four Modbus data tables."""

    COIL = "coil"                      # read fc 1, write fc 5 / 15
    DISCRETE_INPUT = "discrete input"  # read fc 2
    HOLDING = "holding register"       # read fc 3, write fc 6 / 16
    INPUT = "input register"           # read fc 4

    @property
    def writable(self) -> bool:
        return self in (Table.COIL, Table.HOLDING)


class Kind(enum.Enum):
    """How the wire words of a register are interpreted."""

    BOOL = "bool"     # one coil / discrete input
    U16 = "u16"
    S16 = "s16"       # two's complement
    U32 = "u32"       # two words, high word first
    ASCII8 = "ascii8"  # four words, 8 ASCII bytes, big-endian within a word, NUL padded

    @property
    def words(self) -> int:
        return {Kind.U32: 2, Kind.ASCII8: 4}.get(self, 1)


@dataclass(frozen=True)
class Register:
    """One entry of the register map."""

    name: str
    table: Table
    address: int
    kind: Kind
    unit: str = ""
    scale: float = 1.0  # engineering units per LSB
    description: str = ""

    @property
    def words(self) -> int:
        return self.kind.words

    def raw_range(self) -> tuple[int, int]:
        """Integer range the wire encoding can carry."""
        if self.kind is Kind.BOOL:
            return (0, 1)
        if self.kind is Kind.S16:
            return (-0x8000, 0x7FFF)
        if self.kind is Kind.U32:
            return (0, 0xFFFF_FFFF)
        return (0, 0xFFFF)

    def representable_range(self) -> tuple[float, float]:
        lo, hi = self.raw_range()
        return (lo * self.scale, hi * self.scale)


# --- coils (read/write bits) -------------------------------------------------------------------
LASER_ENABLE = Register("LASER_ENABLE", Table.COIL, 0, Kind.BOOL,
                        description="1 = laser current on (refused with exception 4 while the "
                                    "interlock is open or a fault is latched)")
HV_ENABLE = Register("HV_ENABLE", Table.COIL, 1, Kind.BOOL,
                     description="1 = MEMS HV output on (same gating as LASER_ENABLE)")

# --- discrete inputs (read-only bits) ----------------------------------------------------------
INTERLOCK_CLOSED = Register("INTERLOCK_CLOSED", Table.DISCRETE_INPUT, 0, Kind.BOOL,
                            description="1 = safety interlock closed (laser/HV may be enabled)")
LASER_ON = Register("LASER_ON", Table.DISCRETE_INPUT, 1, Kind.BOOL,
                    description="actual laser output state")
HV_ON = Register("HV_ON", Table.DISCRETE_INPUT, 2, Kind.BOOL, description="actual HV output state")
FAULT_ACTIVE = Register("FAULT_ACTIVE", Table.DISCRETE_INPUT, 3, Kind.BOOL,
                        description="1 = at least one fault bit latched")
TEC_SETTLED = Register("TEC_SETTLED", Table.DISCRETE_INPUT, 4, Kind.BOOL,
                       description="1 = |TEC readback - setpoint| <= 0.10 degC")

# --- holding registers (read/write words) ------------------------------------------------------
LASER_CURRENT_SETPOINT = Register("LASER_CURRENT_SETPOINT", Table.HOLDING, 0, Kind.U16, "mA", 0.01,
                                  "laser injection current setpoint")
TEC_SETPOINT = Register("TEC_SETPOINT", Table.HOLDING, 1, Kind.S16, "degC", 0.01,
                        "TEC (laser) temperature setpoint")
HV_SETPOINT = Register("HV_SETPOINT", Table.HOLDING, 2, Kind.U16, "V", 0.01,
                       "MEMS HV supply voltage setpoint")
COMMAND = Register("COMMAND", Table.HOLDING, 3, Kind.U16,
                   description="write a Command code to execute it; reads the last code executed")
HV_HOLD_SETPOINT = Register("HV_HOLD_SETPOINT", Table.HOLDING, 4, Kind.U16, "V", 0.01,
                            "MEMS hold voltage after each pull-in (0 = hold at HV_SETPOINT)")

# --- input registers (read-only words) ---------------------------------------------------------
MODEL = Register("MODEL", Table.INPUT, 0, Kind.ASCII8, description="model name, 8 ASCII chars")
FIRMWARE = Register("FIRMWARE", Table.INPUT, 4, Kind.U16,
                    description="firmware version: high byte major, low byte minor")
MAP_VERSION_REG = Register("MAP_VERSION", Table.INPUT, 5, Kind.U16,
                           description="register map version (this document: 1)")
LASER_CURRENT = Register("LASER_CURRENT", Table.INPUT, 6, Kind.U16, "mA", 0.01,
                         "measured laser current (0 while the laser is off)")
TEC_TEMPERATURE = Register("TEC_TEMPERATURE", Table.INPUT, 7, Kind.S16, "degC", 0.01,
                           "measured laser (TEC thermistor) temperature")
HV_VOLTAGE = Register("HV_VOLTAGE", Table.INPUT, 8, Kind.U16, "V", 0.01,
                      "measured HV output voltage (0 while HV is off)")
FAULTS = Register("FAULTS", Table.INPUT, 9, Kind.U16, description="latched fault bitfield (Fault)")
UPTIME_MS = Register("UPTIME_MS", Table.INPUT, 10, Kind.U32, "ms", 1.0,
                     "time since power-up, wraps after 2^32 ms (49.7 days)")
HEARTBEAT = Register("HEARTBEAT", Table.INPUT, 12, Kind.U16,
                     description="count of Modbus requests served, wraps at 65536")

REGISTER_MAP: tuple[Register, ...] = (
    LASER_ENABLE, HV_ENABLE,
    INTERLOCK_CLOSED, LASER_ON, HV_ON, FAULT_ACTIVE, TEC_SETTLED,
    LASER_CURRENT_SETPOINT, TEC_SETPOINT, HV_SETPOINT, COMMAND, HV_HOLD_SETPOINT,
    MODEL, FIRMWARE, MAP_VERSION_REG, LASER_CURRENT, TEC_TEMPERATURE, HV_VOLTAGE, FAULTS,
    UPTIME_MS, HEARTBEAT,
)


def table_size(table: Table) -> int:
    """Number of addresses (bits or words) the map defines in ``table``, from address 0."""
    return max(r.address + r.words for r in REGISTER_MAP if r.table is table)


def register_at(table: Table, address: int) -> Register | None:
    """The register whose span covers ``address`` in ``table`` (None if unmapped)."""
    for r in REGISTER_MAP:
        if r.table is table and r.address <= address < r.address + r.words:
            return r
    return None


# Contiguous blocks the driver reads in one request.
IDENTITY_BLOCK = (MODEL.address, MAP_VERSION_REG.address + 1 - MODEL.address)        # IR 0..5
STATUS_BLOCK = (LASER_CURRENT.address, HEARTBEAT.address + 1 - LASER_CURRENT.address)  # IR 6..12
FLAGS_BLOCK = (INTERLOCK_CLOSED.address, TEC_SETTLED.address + 1)                     # DI 0..4

#: Band in which TEC_SETTLED is reported (degC).
TEC_SETTLED_BAND_C = 0.10


class Command(enum.IntEnum):
    """Codes for the COMMAND holding register. Unknown codes are refused (exception 3)."""

    NONE = 0x0000
    #: clear latched faults whose cause is gone (INTERLOCK_OPEN stays while the loop is open)
    CLEAR_FAULTS = 0xC1EA


class Fault(enum.Enum):
    """Fault bits of the FAULTS register (value = bit number). Any fault turns laser and HV off."""

    LASER_OVER_CURRENT = 0   # measured current above the hardware limit
    OVER_TEMPERATURE = 1     # laser temperature above the TEC range
    HV_FAULT = 2             # HV over-voltage / output not following setpoint / short
    INTERLOCK_OPEN = 3       # the interlock opened (latched until cleared with the loop closed)
    TEC_FAULT = 4            # TEC out of regulation / thermistor open

    @property
    def mask(self) -> int:
        return 1 << self.value


DEFINED_FAULT_MASK = sum(f.mask for f in Fault)


class ExceptionCode(enum.IntEnum):
    """Modbus exception codes this device uses (Modbus Application Protocol v1.1b3, §7)."""

    ILLEGAL_FUNCTION = 1
    ILLEGAL_DATA_ADDRESS = 2
    ILLEGAL_DATA_VALUE = 3    # value outside the device's hardware limits; unknown command
    SERVER_DEVICE_FAILURE = 4  # enable refused: interlock open or fault latched
    SERVER_DEVICE_BUSY = 6
