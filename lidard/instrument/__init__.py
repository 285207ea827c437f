"""The instrument: drivers and DSP composed into scans, calibrations and a self-test (dissertation §4.4).

Rooms (one responsibility each; the dissertation part each follows is in its docstring):

=====================  ===========================================================================
``types``              what a scan asks for and gets back (ScanRequest, ScanResult, POINT_DTYPE, ...)
``protocol``           the :class:`Instrument` protocol the API, the jobs and the CLI call
``errors``             InstrumentError and its tree; :func:`on_device` names the device of a failure
``devices``            the registry of the four devices (fpsa, awg, digitizer, controller), §4.4.1
``acquisition``        one acquisition lifecycle ready -> start -> read -> stop, with its context
``plan``               scan plans: which pixels, in which order (raster, serpentine, ROI, pixels, adaptive)
``tracking``           a stream's frame planner: survey, then track what moved (pure)
``scan_loop``          a scan as stages: plan -> acquire -> DSP -> points (§4.4.1, §4.4.3)
``points``             DSP results -> point records, batches buffered to bounded memory
``calibration/``       chirp linearization (§2.2), range scale/zero (§2.1.1) and pointing (§4.1.1)
``selftest``           the FPSA row/column switch self-test against the monitor tap (§4.3.3)
``selftest_analysis``  pure checks of the HV readback against the switches' pull-in (§4.2.6)
``safety``             interlock/fault check and the safe-state path (laser and HV off first)
``facade``             :class:`LidarInstrument`, what callers hold
``compose``            the composition root: config -> drivers (+ the simulated bench); the only
                       module of lidard that imports sim_devices
=====================  ===========================================================================

The light names (types, protocol, errors) are imported at once; the ones that pull in drivers and the
DSP (``open_instrument``, ``LidarInstrument``, ...) on first use, so the API and the job queue can
import the types without loading the hardware stack.
"""

from __future__ import annotations

from .._lazy import lazy_getattr


from .errors import (DeviceFault, InstrumentError, NotSimulated, ScanFailed, SceneRejected, SegmentsLost,
                     SimFaultError)
from .protocol import Instrument
from .types import (POINT_DTYPE, CalibrationResult, OutputFormat, PatternKind, ProgressFn, ScanCancelled,
                    ScanProgress, ScanRequest, ScanResult)

# name -> module that defines it, imported on first access (PEP 562)
_LAZY = {
    "open_instrument": "compose",
    "LidarInstrument": "facade",
    "SimHooks": "facade",
    "analyse_selftest": "selftest",
    "SAFETY_CHECK_S": "scan_loop",
    "BATCH_BYTES": "scan_loop",
    "RESUMES": "scan_loop",
    "BATCH_RETRIES": "acquisition",
    "AWG_RATE_HZ": "acquisition",
    "DEVICE_NAMES": "devices",
}

__all__ = ["POINT_DTYPE",  # noqa: PLE0604 - *_LAZY spreads the lazily loaded names (strings)
           "CalibrationResult", "DeviceFault", "Instrument", "InstrumentError", "NotSimulated",
           "OutputFormat", "PatternKind", "ProgressFn", "ScanCancelled", "ScanFailed", "ScanProgress",
           "ScanRequest", "ScanResult", "SceneRejected", "SegmentsLost", "SimFaultError", *_LAZY]


__getattr__ = lazy_getattr(__name__, _LAZY, globals())
