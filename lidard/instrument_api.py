"""Compatibility name for :mod:`lidard.instrument.types` and :mod:`lidard.instrument.protocol`.

The seam's types moved into the instrument package (issue 12); import them from ``lidard.instrument``.
This module only keeps branches written against the old name importable until they are merged.
"""

from .instrument.protocol import Instrument
from .instrument.types import (POINT_DTYPE, CalibrationResult, OutputFormat, PatternKind, ProgressFn,
                               ScanCancelled, ScanProgress, ScanRequest, ScanResult)

__all__ = ["POINT_DTYPE", "CalibrationResult", "Instrument", "OutputFormat", "PatternKind", "ProgressFn",
           "ScanCancelled", "ScanProgress", "ScanRequest", "ScanResult"]
