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
from typing import Any, Callable, Iterator

log = logging.getLogger(__name__)

#: The devices in the order every listing uses (GET /devices, identification, closing).
DEVICE_NAMES = ("fpsa", "awg", "digitizer", "controller")

# The cheapest request that proves a device answers; its reply is the "state" GET /devices shows.
_PROBES: dict[str, Callable[[Any], Any]] = {
    "fpsa": lambda d: d.status(),
    "awg": lambda d: d.errors(),          # SCPI error queue: the AWG has no status word
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
        except Exception as exc:  # reported by devices(); a scan will fail with the cause
            self.identity[name] = f"unreachable: {exc}"

    def _unidentified(self, name: str) -> bool:
        return name not in self.identity or str(self.identity[name]).startswith("unreachable")

    # -- health -----------------------------------------------------------------------------------
    def check_all(self) -> list[dict[str, Any]]:
        """Per device: connected and the cause; a silent device is reconnected once and asked again."""
        return [self.check(name) for name in DEVICE_NAMES]

    def check(self, name: str) -> dict[str, Any]:
        dev, probe = self._drivers[name], _PROBES[name]
        entry: dict[str, Any] = {"name": name, "reconnected": False}
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
                entry.update(connected=False, identity=self.identity.get(name), state="unreachable",
                             faults=[first] + ([f"reconnect: {type(exc2).__name__}: {exc2}"]
                                               if str(exc2) != str(exc) else []))
                return entry
        entry.update(connected=True, identity=self.identity.get(name), state=describe(state),
                     faults=faults_of(state))
        return entry

    def busy_listing(self) -> list[dict[str, Any]]:
        """What GET /devices shows while a job holds the devices and nothing was checked yet."""
        return [{"name": n, "connected": not str(self.identity.get(n, "")).startswith("unreachable"),
                 "reconnected": False, "identity": self.identity.get(n),
                 "state": "busy: in use by the running job", "faults": []} for n in DEVICE_NAMES]

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


def faults_of(state: Any) -> list[str]:
    """The fault names a device's status reply carries (a set, a list or a flag enum), sorted."""
    faults = getattr(state, "faults", None)
    if faults is None:
        return []
    if isinstance(faults, (set, frozenset, list, tuple)):
        return sorted(str(f) for f in faults)
    try:
        return [str(f) for f in type(faults) if f in faults and int(f)]
    except TypeError:
        return [str(faults)] if faults else []
