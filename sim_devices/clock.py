"""Virtual clock shared by every simulated device on one bench.

Simulators never read the wall clock: hardware time is *modelled*. A device that needs time to
pass (a pattern step, a digitizer capture) asks the clock to advance; everything that reads the
clock on the same bench sees the same time. Times are float64 seconds since bench power-up.
"""

from __future__ import annotations

import threading


class VirtualClock:
    """Monotonic simulated time in seconds (float64)."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now_s = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._now_s

    def advance(self, dt_s: float) -> float:
        """Move time forward by ``dt_s`` (>= 0); returns the new time."""
        if not dt_s >= 0.0:
            raise ValueError(f"VirtualClock.advance: dt_s must be >= 0, got {dt_s!r}")
        with self._lock:
            self._now_s += float(dt_s)
            return self._now_s

    def advance_to(self, t_s: float) -> float:
        """Move time forward to ``t_s`` if it lies in the future; never moves backward."""
        with self._lock:
            if t_s > self._now_s:
                self._now_s = float(t_s)
            return self._now_s
