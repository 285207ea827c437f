"""Register map, scaling and limits of the laser / TEC / HV controller (Modbus TCP).

Pure code: no sockets, no pymodbus, no clock. Both the driver (drivers/controller/driver.py) and
the simulated device (sim_devices/controller.py) import this module, so the map lives in one place;
docs/protocols/controller.md is the human-readable copy with golden bytes.

What the controller drives (dissertation):
- the DFB laser (Optilab DFB-1550, §4.4.1 / Fig. 4-29; chirp linearised per §2.2) through its
  injection current, with a TEC holding the laser temperature (wavelength stability);
- the MEMS high-voltage supply of the FPSA: 50 V actuation for the 128x128 array (§4.3, Table of
  §4.3.9), pull-in 32 V / release 29 V for the 20x20 array (§4.2.6, Fig. 4-15);
- a safety interlock that gates the laser and the HV.

Addresses are 0-based PDU addresses (what goes on the wire). Scaled quantities are integers with a
fixed LSB (``Register.scale``, engineering units per LSB): laser current 0.01 mA, TEC 0.01 degC
(signed, two's complement), HV 0.01 V. 32-bit values are sent high word first.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.controller.errors import ConfigError, LimitError, ProtocolError

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


# --- limits -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Limits:
    """Allowed setpoint ranges. The driver holds a (tighter) copy per deployment; the device
    enforces ``HARDWARE_LIMITS`` again on its side."""

    max_laser_current_ma: float
    max_hv_v: float
    tec_range_c: tuple[float, float]

    def __post_init__(self) -> None:
        vals = (self.max_laser_current_ma, self.max_hv_v, *self.tec_range_c)
        if len(self.tec_range_c) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v)
                                                 for v in vals):
            raise ConfigError(f"controller: Limits must be finite numbers, got {self!r}")
        if self.max_laser_current_ma <= 0 or self.max_hv_v <= 0:
            raise ConfigError(f"controller: Limits maxima must be > 0, got {self!r}")
        if not self.tec_range_c[0] < self.tec_range_c[1]:
            raise ConfigError(f"controller: Limits.tec_range_c must be (low, high) with low < high, "
                              f"got {self.tec_range_c!r}")

    def range_of(self, reg: Register) -> tuple[float, float]:
        """Allowed engineering range of a setpoint register."""
        if reg is LASER_CURRENT_SETPOINT:
            return (0.0, float(self.max_laser_current_ma))
        if reg is HV_SETPOINT or reg is HV_HOLD_SETPOINT:
            return (0.0, float(self.max_hv_v))
        if reg is TEC_SETPOINT:
            return (float(self.tec_range_c[0]), float(self.tec_range_c[1]))
        raise KeyError(f"controller: {reg.name} is not a limited setpoint")

    def check(self, reg: Register, value: float) -> float:
        """Return ``value`` as float if it is a finite number inside the range, else LimitError."""
        lo, hi = self.range_of(reg)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise LimitError(reg.name, value, lo, hi, reg.unit)
        v = float(value)
        if not (math.isfinite(v) and lo <= v <= hi):
            raise LimitError(reg.name, value, lo, hi, reg.unit)
        return v


#: What the controller hardware itself accepts. 100 V covers the 50 V actuation of the 128x128
#: FPSA (§4.3) with margin; 250 mA is above a DFB-1550's usual operating current.
HARDWARE_LIMITS = Limits(max_laser_current_ma=250.0, max_hv_v=100.0, tec_range_c=(15.0, 40.0))


# --- scaling ------------------------------------------------------------------------------------
def _check_word(reg: Register, word: object) -> int:
    if isinstance(word, bool) or not isinstance(word, int) or not 0 <= word <= 0xFFFF:
        raise ProtocolError(f"{reg.name} word", word, "a register word must be an int in 0..65535")
    return word


def to_raw(reg: Register, value: float) -> int:
    """Engineering value -> signed/unsigned integer count (round half to even), range-checked
    against what the wire encoding can carry (LimitError otherwise)."""
    lo, hi = reg.representable_range()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise LimitError(reg.name, value, lo, hi, reg.unit)
    raw = round(float(value) / reg.scale)
    rlo, rhi = reg.raw_range()
    if not rlo <= raw <= rhi:
        raise LimitError(reg.name, value, lo, hi, reg.unit)
    return raw


def from_raw(reg: Register, raw: int) -> float:
    return raw * reg.scale


def encode_value(reg: Register, value: float | int | bool | str) -> list[int]:
    """Value -> wire words (list of uint16) for a word register, or [0/1] for a bit."""
    if reg.kind is Kind.BOOL:
        return [1 if value else 0]
    if reg.kind is Kind.ASCII8:
        if not isinstance(value, str):
            raise ProtocolError(reg.name, value, "expected a str")
        data = value.encode("ascii", errors="strict") if value.isascii() else None
        if data is None or len(data) > 8 or not all(0x20 <= b <= 0x7E for b in data):
            raise ProtocolError(reg.name, value, "expected <= 8 printable ASCII characters")
        data = data.ljust(8, b"\x00")
        return [int.from_bytes(data[i:i + 2], "big") for i in range(0, 8, 2)]
    raw = to_raw(reg, value)  # type: ignore[arg-type]
    if reg.kind is Kind.S16:
        return [raw & 0xFFFF]
    if reg.kind is Kind.U32:
        return [(raw >> 16) & 0xFFFF, raw & 0xFFFF]
    return [raw]


def decode_value(reg: Register, words: Sequence[int]) -> float | int | bool | str:
    """Wire words -> engineering value. Raises ProtocolError (only) on words the map forbids."""
    if len(words) != reg.words:
        raise ProtocolError(f"{reg.name} length", len(words), f"expected {reg.words} word(s)")
    ws = [_check_word(reg, w) for w in words]
    if reg.kind is Kind.BOOL:
        if ws[0] not in (0, 1):
            raise ProtocolError(reg.name, ws[0], "a bit must be 0 or 1")
        return bool(ws[0])
    if reg.kind is Kind.ASCII8:
        data = b"".join(w.to_bytes(2, "big") for w in ws)
        text = data.rstrip(b"\x00")
        if not all(0x20 <= b <= 0x7E for b in text):
            raise ProtocolError(reg.name, data, "model name must be printable ASCII, NUL padded")
        return text.decode("ascii")
    if reg.kind is Kind.S16:
        raw = ws[0] - 0x10000 if ws[0] & 0x8000 else ws[0]
    elif reg.kind is Kind.U32:
        raw = (ws[0] << 16) | ws[1]
    else:
        raw = ws[0]
    if reg.scale == 1.0:
        return raw
    return from_raw(reg, raw)


def encode_faults(faults: frozenset[Fault] | set[Fault]) -> int:
    word = 0
    for f in faults:
        word |= f.mask
    return word


def decode_faults(word: int) -> frozenset[Fault]:
    """FAULTS word -> set of Fault. Undefined bits are a ProtocolError: a safety word we cannot
    fully interpret must not be read as 'no fault'."""
    _check_word(FAULTS, word)
    if word & ~DEFINED_FAULT_MASK:
        raise ProtocolError("FAULTS", word, f"undefined fault bits 0x{word & ~DEFINED_FAULT_MASK:04X}")
    return frozenset(f for f in Fault if word & f.mask)


# --- decoded blocks -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Identity:
    model: str
    firmware: str      # "major.minor"
    map_version: int


@dataclass(frozen=True)
class Status:
    laser_current_ma: float
    tec_c: float
    hv_v: float
    faults: frozenset[Fault]
    uptime_ms: int
    heartbeat: int


@dataclass(frozen=True)
class Flags:
    interlock_closed: bool
    laser_on: bool
    hv_on: bool
    fault_active: bool
    tec_settled: bool


def _slice(words: Sequence[int], block: tuple[int, int], reg: Register) -> Sequence[int]:
    start = reg.address - block[0]
    return words[start:start + reg.words]


def decode_identity(words: Sequence[int]) -> Identity:
    if len(words) != IDENTITY_BLOCK[1]:
        raise ProtocolError("identity block length", len(words), f"expected {IDENTITY_BLOCK[1]} words")
    fw = _check_word(FIRMWARE, words[FIRMWARE.address - IDENTITY_BLOCK[0]])
    return Identity(
        model=str(decode_value(MODEL, _slice(words, IDENTITY_BLOCK, MODEL))),
        firmware=f"{fw >> 8}.{fw & 0xFF}",
        map_version=int(decode_value(MAP_VERSION_REG, _slice(words, IDENTITY_BLOCK, MAP_VERSION_REG))),
    )


def encode_firmware(major: int, minor: int) -> int:
    if not (0 <= major <= 255 and 0 <= minor <= 255):
        raise ProtocolError("FIRMWARE", (major, minor), "major and minor must be in 0..255")
    return (major << 8) | minor


def decode_status(words: Sequence[int]) -> Status:
    if len(words) != STATUS_BLOCK[1]:
        raise ProtocolError("status block length", len(words), f"expected {STATUS_BLOCK[1]} words")

    def val(reg: Register) -> float | int | bool | str:
        return decode_value(reg, _slice(words, STATUS_BLOCK, reg))

    return Status(
        laser_current_ma=float(val(LASER_CURRENT)),
        tec_c=float(val(TEC_TEMPERATURE)),
        hv_v=float(val(HV_VOLTAGE)),
        faults=decode_faults(_slice(words, STATUS_BLOCK, FAULTS)[0]),
        uptime_ms=int(val(UPTIME_MS)),
        heartbeat=int(val(HEARTBEAT)),
    )


def decode_flags(bits: Sequence[bool | int]) -> Flags:
    if len(bits) < FLAGS_BLOCK[1]:
        raise ProtocolError("flags block length", len(bits), f"expected {FLAGS_BLOCK[1]} bits")
    b = [bool(x) for x in bits[:FLAGS_BLOCK[1]]]
    return Flags(
        interlock_closed=b[INTERLOCK_CLOSED.address],
        laser_on=b[LASER_ON.address],
        hv_on=b[HV_ON.address],
        fault_active=b[FAULT_ACTIVE.address],
        tec_settled=b[TEC_SETTLED.address],
    )
