"""Command-line entry points: ``lidard`` (the daemon, :mod:`.daemon`) and ``lidarctl`` (the client and
offline tools, :mod:`.lidarctl`, one module per command group: scan, scans, devices, control, faults,
calibration, selftest, optics).

``base`` holds the one-line error contract and the hook into the composition root
(``base.open_instrument``); ``client`` the HTTP client; ``embedded`` the ``--sim`` bench; ``progress``
and ``output`` how results are shown.
"""

from .base import CliError
from .daemon import build_parser as build_lidard_parser
from .daemon import is_loopback
from .daemon import main as lidard_main
from .lidarctl import build_parser as build_lidarctl_parser
from .lidarctl import main as lidarctl_main

__all__ = ["CliError", "build_lidarctl_parser", "build_lidard_parser", "is_loopback", "lidarctl_main",
           "lidard_main"]
