"""Persistent state of the daemon: scans, chirp and geometric calibrations, the calibration cache.

``database.py`` holds :class:`Store` (SQLite + files under the data directory, one daemon per
directory); ``geometry.py`` the range and pointing calibrations it keeps as ``Store.geometry``;
``calcache.py`` the user's cache of factory calibrations for one-shot ``--sim`` commands.
"""

from lidard.store.database import (
                                   LOCK_NAME,
                                   SCAN_STATES,
                                   TERMINAL_STATES,
                                   DataDirLocked,
                                   ScanRecord,
                                   Store,
                                   StoreError,
                                   new_id,
)
from lidard.store.geometry import (
                                   GEOMETRY_KINDS,
                                   CalibrationRecord,
                                   GeometryCalibrations,
)

__all__ = ["GEOMETRY_KINDS", "LOCK_NAME", "SCAN_STATES", "TERMINAL_STATES", "CalibrationRecord", "DataDirLocked",
           "GeometryCalibrations", "ScanRecord", "Store", "StoreError", "new_id"]
