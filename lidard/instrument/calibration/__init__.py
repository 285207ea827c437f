"""Calibrations the instrument learns through its own channels (the bench's truths stay hidden).

One module per calibration, each a small class over the acquisition lifecycle and the safety monitor:

* :mod:`.linearization` -- the laser chirp's iterative learning pre-distortion through the monitor
  MZI (dissertation §2.2);
* :mod:`.health` -- the linearization health check before each scan (issue 13).

Range scale/zero, pointing and I/Q-imbalance calibrations go here as siblings.
"""

from .health import HealthCheck, LinearizationHealth
from .linearization import Linearization

__all__ = ["HealthCheck", "Linearization", "LinearizationHealth"]
