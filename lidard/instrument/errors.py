"""Errors of the instrument package, and how a driver failure gets the name of its device.

Tree (every class is a :class:`lidard.errors.LidardError`, reported to users as one line)::

    InstrumentError            a scan, calibration or self-test could not run; names device and cause
    +-- DeviceFault            a driver call failed; ``.device``, ``.command``, ``.cause`` (the driver's error)
    +-- SegmentsLost           digitizer segments could not be read (refused, or retries exhausted)
    +-- ScanFailed             a device stayed down mid-scan; ``.partial`` holds the points measured before
    +-- NotSimulated           a simulation-only operation was asked of real hardware
    +-- SimFaultError          the simulated bench refused a fault (also a ValueError)
    +-- SceneRejected          the simulated bench refused a scene (also a ValueError)
    +-- FaultsStillOpen        a fault acknowledgement was refused: ``.still_open`` names what is still open

The device a failure belongs to is named where the driver is called (:func:`on_device` around each
step of the acquisition lifecycle), never guessed from an exception's module or message. An exception
that names its device itself (a ``.device`` attribute, as the drivers' ``DeviceError(device, command)``
carries) wins over the caller's name. (Plumbing, not physics: no part of the dissertation; the device
names are those of the bench in §4.4.1.)
"""

from __future__ import annotations

from contextlib import contextmanager
from collections.abc import Iterator

from ..errors import LidardError
from .types import ScanResult


class InstrumentError(LidardError):
    """A scan or calibration could not run; the message names the device and the cause."""


class DeviceFault(InstrumentError):
    """A driver call failed. ``str()`` is ``"<device>: <ErrorType>: <message>"``; the driver's own
    exception is ``cause`` (and ``__cause__``)."""

    def __init__(self, device: str, command: str, cause: BaseException):
        super().__init__(f"{device}: {type(cause).__name__}: {cause}")
        self.device = device
        self.command = command
        self.cause = cause


class SegmentsLost(InstrumentError):
    """Digitizer segments could not be read: refused (stall) or still failing after the re-reads.
    The scan loop answers it by checking safety and then resuming as a new acquisition."""


class ScanFailed(InstrumentError):
    """A device stayed down mid-scan. ``partial`` holds the points measured before (may be None)."""

    def __init__(self, message: str, partial: ScanResult | None = None):
        super().__init__(message)
        self.partial = partial


class NotSimulated(InstrumentError):
    """A simulation-only operation (scene, fault injection) was asked of real hardware."""

    http_status = 409


class SimFaultError(InstrumentError, ValueError):
    """The simulated bench refused a fault (unknown kind or bad parameter); names it."""

    http_status = 422


class SceneRejected(InstrumentError, ValueError):
    """The simulated bench refused a scene; the message names the key or target that is wrong."""

    http_status = 422


class FaultsStillOpen(InstrumentError):
    """An acknowledgement of the controller's latched faults was refused: a cause is still present.
    ``still_open`` names each (``INTERLOCK_OPEN``, ``HV_FAULT``, ...) with why."""

    http_status = 409

    def __init__(self, still_open: list[str]):
        self.still_open = list(still_open)
        super().__init__("controller: cannot acknowledge, still open: " + "; ".join(self.still_open))


def device_of(exc: BaseException, default: str = "instrument") -> str:
    """The device an exception names itself (``exc.device``), else ``default`` (the caller's)."""
    dev = getattr(exc, "device", None)
    return dev if isinstance(dev, str) and dev else default


def driver_error(exc: BaseException) -> BaseException:
    """The driver's own exception behind a :class:`DeviceFault` (else ``exc``): a ScanFailed is
    chained to it directly, so its one-line description (``jobs.describe_error``) reads as before."""
    return exc.cause if isinstance(exc, DeviceFault) else exc


def describe_failure(exc: BaseException) -> str:
    """``"<device>: <ErrorType>: <message>"`` for a failure inside a scan (a DeviceFault already is)."""
    if isinstance(exc, DeviceFault):
        return str(exc)
    return f"{device_of(exc)}: {type(exc).__name__}: {exc}"


@contextmanager
def on_device(device: str, command: str) -> Iterator[None]:
    """Run driver calls of ``device``: a failure leaves as :class:`DeviceFault` naming it.

    Our own errors (an :class:`InstrumentError`, e.g. a refused drive waveform) pass unchanged.
    """
    try:
        yield
    except InstrumentError:
        raise
    except Exception as exc:
        raise DeviceFault(device_of(exc, device), command, exc) from exc
