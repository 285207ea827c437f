"""Register map, scaling and limits of the laser / TEC / HV controller (Modbus TCP).

Pure code: no sockets, no pymodbus, no clock. Both the driver (drivers/controller/driver.py) and
the simulated device (sim_devices/controller/device.py) import this module, so the map lives in one place;
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

Parts: the register map itself (tables, registers, blocks, command/fault/exception codes) is
``protocol_map.py``; this module adds the hardware limits, the scaling between engineering values
and register words, and the decoded blocks. Every name of the codec is importable from here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.controller.errors import ConfigError, LimitError, bad_value
from drivers.controller.protocol_map import (
    COMMAND,
    DEFINED_FAULT_MASK,
    FAULTS,
    FAULT_ACTIVE,
    FIRMWARE,
    FLAGS_BLOCK,
    HEARTBEAT,
    HV_ENABLE,
    HV_HOLD_SETPOINT,
    HV_ON,
    HV_SETPOINT,
    HV_VOLTAGE,
    IDENTITY_BLOCK,
    INTERLOCK_CLOSED,
    LASER_CURRENT,
    LASER_CURRENT_SETPOINT,
    LASER_ENABLE,
    LASER_ON,
    MAP_VERSION,
    MAP_VERSION_REG,
    MODEL,
    REGISTER_MAP,
    STATUS_BLOCK,
    TEC_SETPOINT,
    TEC_SETTLED,
    TEC_SETTLED_BAND_C,
    TEC_TEMPERATURE,
    UPTIME_MS,
    Command,
    ExceptionCode,
    Fault,
    Kind,
    Register,
    Table,
    register_at,
    table_size,
)


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
        raise bad_value(f"{reg.name} word", word, "a register word must be an int in 0..65535")
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
            raise bad_value(reg.name, value, "expected a str")
        data = value.encode("ascii", errors="strict") if value.isascii() else None
        if data is None or len(data) > 8 or not all(0x20 <= b <= 0x7E for b in data):
            raise bad_value(reg.name, value, "expected <= 8 printable ASCII characters")
        data = data.ljust(8, b"\x00")
        return [int.from_bytes(data[i:i + 2], "big") for i in range(0, 8, 2)]
    raw = to_raw(reg, value)  # type: ignore[arg-type]
    if reg.kind is Kind.S16:
        return [raw & 0xFFFF]
    if reg.kind is Kind.U32:
        return [(raw >> 16) & 0xFFFF, raw & 0xFFFF]
    return [raw]


def decode_value(reg: Register, words: Sequence[int]) -> float | int | bool | str:
    """Wire words -> engineering value. Raises a PayloadError (only) on words the map forbids."""
    if len(words) != reg.words:
        raise bad_value(f"{reg.name} length", len(words), f"expected {reg.words} word(s)")
    ws = [_check_word(reg, w) for w in words]
    if reg.kind is Kind.BOOL:
        if ws[0] not in (0, 1):
            raise bad_value(reg.name, ws[0], "a bit must be 0 or 1")
        return bool(ws[0])
    if reg.kind is Kind.ASCII8:
        data = b"".join(w.to_bytes(2, "big") for w in ws)
        text = data.rstrip(b"\x00")
        if not all(0x20 <= b <= 0x7E for b in text):
            raise bad_value(reg.name, data, "model name must be printable ASCII, NUL padded")
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
    """FAULTS word -> set of Fault. Undefined bits are a PayloadError: a safety word we cannot
    fully interpret must not be read as 'no fault'."""
    _check_word(FAULTS, word)
    if word & ~DEFINED_FAULT_MASK:
        raise bad_value("FAULTS", word, f"undefined fault bits 0x{word & ~DEFINED_FAULT_MASK:04X}")
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
        raise bad_value("identity block length", len(words), f"expected {IDENTITY_BLOCK[1]} words")
    fw = _check_word(FIRMWARE, words[FIRMWARE.address - IDENTITY_BLOCK[0]])
    return Identity(
        model=str(decode_value(MODEL, _slice(words, IDENTITY_BLOCK, MODEL))),
        firmware=f"{fw >> 8}.{fw & 0xFF}",
        map_version=int(decode_value(MAP_VERSION_REG, _slice(words, IDENTITY_BLOCK, MAP_VERSION_REG))),
    )


def encode_firmware(major: int, minor: int) -> int:
    if not (0 <= major <= 255 and 0 <= minor <= 255):
        raise bad_value("FIRMWARE", (major, minor), "major and minor must be in 0..255")
    return (major << 8) | minor


def decode_status(words: Sequence[int]) -> Status:
    if len(words) != STATUS_BLOCK[1]:
        raise bad_value("status block length", len(words), f"expected {STATUS_BLOCK[1]} words")

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
        raise bad_value("flags block length", len(bits), f"expected {FLAGS_BLOCK[1]} bits")
    b = [bool(x) for x in bits[:FLAGS_BLOCK[1]]]
    return Flags(
        interlock_closed=b[INTERLOCK_CLOSED.address],
        laser_on=b[LASER_ON.address],
        hv_on=b[HV_ON.address],
        fault_active=b[FAULT_ACTIVE.address],
        tec_settled=b[TEC_SETTLED.address],
    )


__all__ = ["COMMAND", "Command", "DEFINED_FAULT_MASK", "ExceptionCode", "FAULTS", "FAULT_ACTIVE", "FIRMWARE",
           "FLAGS_BLOCK", "Fault", "Flags", "HARDWARE_LIMITS", "HEARTBEAT", "HV_ENABLE", "HV_HOLD_SETPOINT",
           "HV_ON", "HV_SETPOINT", "HV_VOLTAGE", "IDENTITY_BLOCK", "INTERLOCK_CLOSED", "Identity", "Kind",
           "LASER_CURRENT", "LASER_CURRENT_SETPOINT", "LASER_ENABLE", "LASER_ON", "Limits", "MAP_VERSION",
           "MAP_VERSION_REG", "MODEL", "REGISTER_MAP", "Register", "STATUS_BLOCK", "Status", "TEC_SETPOINT",
           "TEC_SETTLED", "TEC_SETTLED_BAND_C", "TEC_TEMPERATURE", "Table", "UPTIME_MS", "decode_faults",
           "decode_flags", "decode_identity", "decode_status", "decode_value", "encode_faults",
           "encode_firmware", "encode_value", "from_raw", "register_at", "table_size", "to_raw"]
