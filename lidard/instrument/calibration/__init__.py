"""Calibrations the instrument learns through its own channels (the bench's truths stay hidden).

One module per calibration:

* :mod:`.linearization` -- the laser chirp's iterative learning pre-distortion through the monitor
  MZI (dissertation §2.2);
* :mod:`.range` -- range scale (the effective monitor delay) and zero offset from a plate at known
  distances (§2.1.1, eq. 2-3);
* :mod:`.pointing` -- the pointing model (focal length, decentre, rotation, distortion; §4.1.1,
  eq. 4-1) from targets of known geometry;
* :mod:`.applied` -- what an instrument applies of the last two; :mod:`.procedures` -- the measuring
  procedures over an instrument (and the benchmarks' entry points).
* :mod:`.health` -- the linearization health check before each scan.

Names are imported on first use (PEP 562): the API and the job queue load the light modules
(``applied``, ``range``) without the DSP that the linearization pulls in.
"""

from __future__ import annotations

from ..._lazy import lazy_getattr


_LAZY = {
    "Linearization": "linearization",
    "HealthCheck": "health",
    "LinearizationHealth": "health",
    "AppliedCalibrations": "applied",
    "CalibrationRefused": "range",
    "run_range_calibration": "procedures",
    "run_pointing_calibration": "procedures",
}

__all__ = list(_LAZY)


__getattr__ = lazy_getattr(__name__, _LAZY, globals())
