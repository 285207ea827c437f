"""Fault catalogue of the simulated bench: which faults can be injected, their parameters, and the
serial line-noise filter.

Where this deviates from / adds to the task brief (read this first):

* ``digitizer_overrange`` ``gain`` is a linear factor on the beat (signal and front-end noise),
  default **1000**, not 20: the beat of a paper target at 0.9 m is ~0.75 mV on sim.toml's 1 V
  range, so a gain of 20 does not clip anything (about 700 or more does).
* ``n`` of ``usb_disconnect``: the device is gone for n failed accesses (opens included), then
  plugged back by itself; omitted = until cleared. A re-plugged device resets its USB-side state
  (an armed digitizer acquisition, a USBTMC session), its settings survive. Old pyusb handles
  work again after a re-plug (a real host would need a re-find; drivers should re-find anyway).
* ``serial_drop``, ``serial_flip``, ``serial_disconnect``, ``digitizer_overrange``, ``hv_fault``
  ``interlock_open`` and ``tec_offset`` are one per bench: injecting again replaces the earlier one. Faults with a
  count ``n`` leave ``Bench.active_faults()`` once the count is used up.
* ``interlock_open`` ``after_segments`` counts segments the bench synthesizes (a host re-read of
  earlier segments counts too, and re-reads after the opening come back dark).

Every fault is a *physical or wire-level* event on the bench, never a flag the daemon could read:

========================  =======================================================================
kind                      parameters (``*`` required)
========================  =======================================================================
``serial_drop``           ``rate``* probability that a byte is lost, each direction, each byte
``serial_flip``           ``rate``* probability that a byte has one random bit flipped
``serial_disconnect``     ``reconnect_after_s`` (virtual s; omitted: until cleared). The pty is
                          closed; reconnecting opens a NEW pty behind the same stable symlink.
``usb_timeout``           ``device``* ("awg" | "digitizer"), ``n`` transfers (omitted: until
``usb_stall``             cleared); timeout = the transfer times out, stall = EPIPE;
``usb_disconnect``        disconnect = ENODEV and the device leaves the bus enumeration
                          (with ``n``: it comes back after n failed transfers).
``digitizer_overrange``   ``gain`` (linear, default 1000): the analog front end scales the beat
                          (signal and noise) by ``gain``; it clips at full scale and the segment
                          header's overrange flag is set on clipped segments. NOTE: a paper
                          target at 0.9 m gives a ~0.75 mV beat on sim.toml's 1 V range, so a
                          gain of 20 does NOT clip it; ~700 or more does.
``modbus_exception``      ``code``* (a Modbus exception code), ``n`` requests (omitted: until
                          cleared) answered with it, nothing executed.
``modbus_timeout``        ``n`` responses swallowed (omitted: until cleared); requests execute.
``interlock_open``        ``at_s`` (absolute virtual time, default now) or ``after_segments``
                          (opens at the trigger of the n-th segment the digitizer produces from
                          now on, i.e. mid-scan). Laser and HV drop at once; INTERLOCK_OPEN latches.
``stuck_switch``          ``line``* ("row" | "col"), ``index``*, ``state``* ("on" | "off"): that
                          MEMS switch ignores its drive from now on (§4.2.6 stiction / a dead
                          actuator), so light leaves through the wrong pixels or not at all.
``hv_fault``              none: the HV supply trips to 0 V, HV_FAULT latches (and stays latched
                          through CLEAR_FAULTS until the fault is cleared on the bench).
``tec_offset``            ``offset_c``* (C, within +-10): the laser chip's TRUE temperature steps
                          by offset_c from now on (a thermistor offset or a new thermal gradient,
                          which only a calibration can see); the TEC readback still shows the set point. Clearing it
                          steps back. One per bench.
========================  =======================================================================

``validate_fault(kind, params)`` returns the normalised parameters or raises ``ValueError`` naming
the kind and the parameter; ``lidard.config`` calls it for ``[[sim.faults]]`` entries. This module is
pure (numpy + stdlib): no bench, no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

USB_DEVICES = ("awg", "digitizer")
#: Modbus exception codes defined by the Modbus application protocol v1.1b3 (§7).
MODBUS_EXCEPTION_CODES = (1, 2, 3, 4, 5, 6, 8, 10, 11)

#: a larger step of the laser's true temperature is a broken TEC, not a drift
MAX_TEC_OFFSET_C = 10.0

_REQUIRED = object()
_Checker = Any  # (kind, name, value) -> normalised value, or ValueError


def _rate(kind: str, name: str, v: Any) -> float:
    x = _number(kind, name, v)
    if not 0.0 <= x <= 1.0:
        raise ValueError(f"fault {kind}: {name} must be a probability in 0..1, got {v!r}")
    return x


def _number(kind: str, name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f"fault {kind}: {name} must be a number, got {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise ValueError(f"fault {kind}: {name} must be finite, got {v!r}")
    return x


def _positive(kind: str, name: str, v: Any) -> float:
    x = _number(kind, name, v)
    if not x > 0:
        raise ValueError(f"fault {kind}: {name} must be > 0, got {v!r}")
    return x


def _non_negative(kind: str, name: str, v: Any) -> float:
    x = _number(kind, name, v)
    if not x >= 0:
        raise ValueError(f"fault {kind}: {name} must be >= 0, got {v!r}")
    return x


def _int(kind: str, name: str, v: Any, minimum: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or float(v) != int(v):
        raise ValueError(f"fault {kind}: {name} must be an integer, got {v!r}")
    if int(v) < minimum:
        raise ValueError(f"fault {kind}: {name} must be >= {minimum}, got {v!r}")
    return int(v)


def _count(kind: str, name: str, v: Any) -> int:
    return _int(kind, name, v, 1)


def _index(kind: str, name: str, v: Any) -> int:
    return _int(kind, name, v, 0)


def _choice(*allowed: str):
    def check(kind: str, name: str, v: Any) -> str:
        if v not in allowed:
            raise ValueError(f"fault {kind}: {name} must be one of {', '.join(map(repr, allowed))}, "
                             f"got {v!r}")
        return v
    return check


def _modbus_code(kind: str, name: str, v: Any) -> int:
    c = _int(kind, name, v, 1)
    if c not in MODBUS_EXCEPTION_CODES:
        raise ValueError(f"fault {kind}: {name} must be a Modbus exception code "
                         f"{MODBUS_EXCEPTION_CODES}, got {v!r}")
    return c


def _tec_step(kind: str, name: str, v: Any) -> float:
    x = _number(kind, name, v)
    if abs(x) > MAX_TEC_OFFSET_C:
        raise ValueError(f"fault {kind}: {name} must be within +-{MAX_TEC_OFFSET_C:g} C, got {v!r}")
    return x


_USB = {"device": (_choice(*USB_DEVICES), _REQUIRED), "n": (_count, None)}

# kind -> {param: (checker, default)}; default _REQUIRED = must be given, None = absent / until cleared
CATALOGUE: dict[str, dict[str, tuple[_Checker, Any]]] = {
    "serial_drop": {"rate": (_rate, _REQUIRED)},
    "serial_flip": {"rate": (_rate, _REQUIRED)},
    "serial_disconnect": {"reconnect_after_s": (_positive, None)},
    "usb_timeout": dict(_USB),
    "usb_stall": dict(_USB),
    "usb_disconnect": dict(_USB),
    "digitizer_overrange": {"gain": (_positive, 1000.0)},
    "modbus_exception": {"code": (_modbus_code, _REQUIRED), "n": (_count, None)},
    "modbus_timeout": {"n": (_count, None)},
    "interlock_open": {"at_s": (_non_negative, None), "after_segments": (_index, None)},
    "stuck_switch": {"line": (_choice("row", "col"), _REQUIRED), "index": (_index, _REQUIRED),
                     "state": (_choice("on", "off"), _REQUIRED)},
    "hv_fault": {},
    "tec_offset": {"offset_c": (_tec_step, _REQUIRED)},
}

FAULT_KINDS: tuple[str, ...] = tuple(CATALOGUE)


def validate_fault(kind: Any, params: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Check ``kind`` and its parameters against the catalogue.

    Returns ``{"kind": kind, **params}`` with defaults filled in (``None`` = "until cleared" / "now"
    / absent). Raises ``ValueError`` naming the unknown kind, the unknown or missing parameter, or
    the bad value.
    """
    if not isinstance(kind, str) or kind not in CATALOGUE:
        raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
    params = dict(params or {})
    params.pop("kind", None)
    spec = CATALOGUE[kind]
    unknown = sorted(set(params) - set(spec))
    if unknown:
        allowed = ", ".join(spec) or "none"
        raise ValueError(f"fault {kind}: unknown parameter {unknown[0]!r} (allowed: {allowed})")
    out: dict[str, Any] = {"kind": kind}
    for name, (check, default) in spec.items():
        if name in params and params[name] is not None:
            out[name] = check(kind, name, params[name])
        elif default is _REQUIRED:
            raise ValueError(f"fault {kind}: parameter {name!r} is required")
        else:
            out[name] = default
    if kind == "interlock_open" and out["at_s"] is not None and out["after_segments"] is not None:
        raise ValueError("fault interlock_open: give at_s or after_segments, not both")
    return out


class SerialLineNoise:
    """Byte drops and single-bit flips on a serial line, each direction, seeded.

    Models a marginal UART link (bad ground, long cable): each byte independently is lost with
    probability ``drop_rate``; each surviving byte has one uniformly chosen bit inverted with
    probability ``flip_rate``. Thread-safe enough for one reader thread per direction (the pty
    server calls it from its one thread).
    """

    def __init__(self, seed: int | tuple[int, ...] = 0) -> None:
        self.drop_rate = 0.0
        self.flip_rate = 0.0
        self._rng = np.random.default_rng(seed)
        self.bytes_dropped = 0
        self.bytes_flipped = 0

    @property
    def active(self) -> bool:
        return self.drop_rate > 0.0 or self.flip_rate > 0.0

    def apply(self, data: bytes) -> bytes:
        """The bytes that arrive at the far end when ``data`` is sent."""
        if not data or not self.active:
            return data
        arr = np.frombuffer(data, dtype=np.uint8)
        if self.drop_rate > 0.0:
            keep = self._rng.random(arr.size) >= self.drop_rate
            self.bytes_dropped += int(arr.size - keep.sum())
            arr = arr[keep]
        if self.flip_rate > 0.0 and arr.size:
            hit = self._rng.random(arr.size) < self.flip_rate
            k = int(hit.sum())
            if k:
                arr = arr.copy()
                arr[hit] ^= (1 << self._rng.integers(0, 8, k)).astype(np.uint8)
                self.bytes_flipped += k
        return arr.tobytes()


__all__ = ["CATALOGUE", "FAULT_KINDS", "MODBUS_EXCEPTION_CODES", "SerialLineNoise", "USB_DEVICES",
           "validate_fault"]
