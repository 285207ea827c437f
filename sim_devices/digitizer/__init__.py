"""The simulated digitizer: a USB peer of ``drivers.digitizer`` and its analog front end."""

from sim_devices.digitizer.device import (
    CaptureConfig,
    CapturedSegments,
    SegmentSource,
    SimDigitizer,
)

__all__ = ["CaptureConfig", "CapturedSegments", "SegmentSource", "SimDigitizer"]
