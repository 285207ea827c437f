"""The one registry of the instrument's four devices, iterated wherever "every device" is meant.

The bench of dissertation §4.4.1 (Fig. 4-14): the FPGA that steps the FPSA's row/column switches
(``fpsa``), the arbitrary waveform generator driving the laser's chirp (``awg``), the digitizer
recording the beat and monitor channels (``digitizer``) and the laser/HV controller (``controller``).
Identification, the health check of GET /devices (with one reconnect) and closing go through
:class:`DeviceRegistry`; nothing else lists the names by hand.
"""

from __future__ import annotations

import dataclasses
import enum

import logging
from typing import Any
from collections.abc import Callable, Iterator

log = logging.getLogger(__name__)

#: The devices in the order every listing uses (GET /devices, identification, closing).
DEVICE_NAMES = ("fpsa", "awg", "digitizer", "controller")

class ErrorQueue(tuple):
    """The AWG's drained SCPI error queue, ``((code, text), ...)``: the AWG has no status word, so an
    empty queue is its "ready"."""


# The cheapest request that proves a device answers; its reply is the "state" GET /devices shows
# (as a line, :func:`describe`) and its "status" (as data, :func:`as_data`).
_PROBES: dict[str, Callable[[Any], Any]] = {
    "fpsa": lambda d: d.status(),
    "awg": lambda d: ErrorQueue(tuple(d.errors())),
    "digitizer": lambda d: d.status(),
    "controller": lambda d: d.status(),
}
# Devices holding a link that must be released on close (the USB devices are released by pyusb).
_CLOSED_ON_EXIT = ("fpsa", "controller")


class DeviceRegistry:
    """The drivers by name, with their identities and last health check."""

    def __init__(self, fpsa: Any, awg: Any, digitizer: Any, controller: Any):
        self._drivers: dict[str, Any] = {"fpsa": fpsa, "awg": awg, "digitizer": digitizer,
                                         "controller": controller}
        self.identity: dict[str, Any] = {}
        self.identity_data: dict[str, Any] = {}

    def __getitem__(self, name: str) -> Any:
        return self._drivers[name]

    def items(self) -> Iterator[tuple[str, Any]]:
        return ((n, self._drivers[n]) for n in DEVICE_NAMES)

    # -- identification ---------------------------------------------------------------------------
    def identify_all(self) -> None:
        for name in DEVICE_NAMES:
            self.identify(name)

    def identify(self, name: str) -> None:
        try:
            ident = self._drivers[name].identify()
            self.identity[name] = ident if isinstance(ident, str) else describe(ident)
            # a plain identification string (the digitizer's *IDN? answer) is kept whole
            self.identity_data[name] = {"idn": ident} if isinstance(ident, str) else as_data(ident)
        except Exception as exc:  # reported by devices(); a scan will fail with the cause
            self.identity[name] = f"unreachable: {exc}"
            self.identity_data[name] = None

    def _unidentified(self, name: str) -> bool:
        return name not in self.identity or str(self.identity[name]).startswith("unreachable")

    # -- health -----------------------------------------------------------------------------------
    def check_all(self) -> list[dict[str, Any]]:
        """Per device: connected and the cause; a silent device is reconnected once and asked again."""
        return [self.check(name) for name in DEVICE_NAMES]

    def check(self, name: str) -> dict[str, Any]:
        dev, probe = self._drivers[name], _PROBES[name]
        entry: dict[str, Any] = {"name": name, "reconnected": False, "busy": False}
        n_before = getattr(dev, "reconnect_count", 0)
        try:
            state = probe(dev)
            # the driver may have reopened its link by itself while answering
            entry["reconnected"] = getattr(dev, "reconnect_count", 0) != n_before
        except Exception as exc:
            first = f"{type(exc).__name__}: {exc}"
            try:
                dev.reconnect()
                state = probe(dev)
                entry["reconnected"] = True
                log.warning("%s: reconnected (was: %s)", name, first)
                if self._unidentified(name):
                    self.identify(name)
            except Exception as exc2:
                entry.update(connected=False, identity=self.identity.get(name), state="unreachable", status=None,
                             identity_fields=self.identity_data.get(name),
                             faults=[first] + ([f"reconnect: {type(exc2).__name__}: {exc2}"]
                                               if str(exc2) != str(exc) else []))
                return entry
        entry.update(connected=True, identity=self.identity.get(name), state=describe(state),
                     status=as_data(state), identity_fields=self.identity_data.get(name), faults=faults_of(state))
        return entry

    def busy_listing(self) -> list[dict[str, Any]]:
        """What GET /devices shows while a job holds the devices and nothing was checked yet."""
        return [{"name": n, "connected": not str(self.identity.get(n, "")).startswith("unreachable"),
                 "reconnected": False, "identity": self.identity.get(n), "identity_fields": self.identity_data.get(n),
                 "state": "not checked yet (in use by the running job)", "status": None, "busy": True,
                 "faults": []} for n in DEVICE_NAMES]

    def close(self) -> None:
        for name in _CLOSED_ON_EXIT:
            try:
                self._drivers[name].close()
            except Exception:
                pass


def describe(reply: Any) -> str:
    """A device's status or identity reply as one readable line for people (GET /devices, the
    viewer, ``lidarctl devices``): ``key=value`` pairs of a dataclass or named tuple, enum members by
    name, sets as sorted names, floats to 4 significant digits; never a Python repr."""
    if isinstance(reply, ErrorQueue):
        return "; ".join(f"error {c}: {t}" for c, t in reply) if reply else "ready (error queue empty)"
    if dataclasses.is_dataclass(reply) and not isinstance(reply, type):
        pairs = [(f.name, getattr(reply, f.name)) for f in dataclasses.fields(reply)]
    elif isinstance(reply, tuple) and hasattr(reply, "_fields"):
        pairs = list(zip(reply._fields, reply))
    else:
        return _plain(reply)
    return ", ".join(f"{k}={_plain(v)}" for k, v in pairs)


def _plain(v: Any) -> str:
    if isinstance(v, enum.Flag) and not isinstance(v, enum.IntEnum):
        names = [m.name for m in type(v) if m.value and m in v and m.name]
        return "+".join(names) if names else "none"
    if isinstance(v, enum.Enum):
        return str(v.name)
    if isinstance(v, (set, frozenset)):
        return "+".join(sorted(_plain(x) for x in v)) or "none"
    if isinstance(v, (list, tuple)):
        if not v:
            return "none"
        return "[" + ", ".join(_plain(x) for x in v) + "]" if len(v) <= 8 else f"{len(v)} values"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def as_data(reply: Any) -> Any:
    """A device's status or identity reply as JSON data (GET /devices ``status``/``identity_fields``):
    a dataclass or named tuple as an object of its fields, enum members by name, flags and sets as
    sorted lists of names, tuples as lists; the AWG's error queue as ``{"error_queue": [...]}``."""
    if isinstance(reply, ErrorQueue):
        return {"error_queue": [{"code": int(c), "text": str(t)} for c, t in reply]}
    if dataclasses.is_dataclass(reply) and not isinstance(reply, type):
        return {f.name: as_data(getattr(reply, f.name)) for f in dataclasses.fields(reply)}
    if isinstance(reply, tuple) and hasattr(reply, "_fields"):
        return {k: as_data(v) for k, v in zip(reply._fields, reply)}
    if isinstance(reply, enum.Flag) and not isinstance(reply, enum.IntEnum):
        return [m.name for m in type(reply) if m.value and m in reply and m.name]
    if isinstance(reply, enum.Enum):
        return reply.name
    if isinstance(reply, (set, frozenset)):
        return sorted(as_data(x) for x in reply)
    if isinstance(reply, (list, tuple)):
        return [as_data(x) for x in reply]
    if isinstance(reply, dict):
        return {str(k): as_data(v) for k, v in reply.items()}
    if isinstance(reply, (bool, int, float, str)) or reply is None:
        return reply
    if hasattr(reply, "item"):       # numpy scalars
        return reply.item()
    return str(reply)


def faults_of(state: Any) -> list[str]:
    """The fault names a device's status reply carries (a set, a list or a flag enum): names, never
    the flag's integer (``str()`` of an IntFlag member is its value)."""
    faults = getattr(state, "faults", None)
    if faults is None:
        return []
    if isinstance(faults, enum.Flag):
        return [m.name for m in type(faults) if m.value and m in faults and m.name]
    if isinstance(faults, (set, frozenset, list, tuple)):
        return sorted(f.name if isinstance(f, enum.Enum) else str(f) for f in faults)
    return [str(faults)] if faults else []
