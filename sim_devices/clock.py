"""Virtual clock shared by every simulated device on one bench.

Simulators never read the wall clock: hardware time is *modelled*. A device that needs time to
pass (a pattern step, a digitizer capture) asks the clock to advance; everything that reads the
clock on the same bench sees the same time. Times are float64 seconds since bench power-up.
"""

from __future__ import annotations

import heapq
import itertools
import threading
from collections.abc import Callable


class VirtualClock:
    """Monotonic simulated time in seconds (float64)."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now_s = float(start_s)
        self._lock = threading.Lock()
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._cancelled: set[int] = set()
        self._ids = itertools.count(1)

    def now(self) -> float:
        with self._lock:
            return self._now_s

    def advance(self, dt_s: float) -> float:
        """Move time forward by ``dt_s`` (>= 0); returns the new time."""
        if not dt_s >= 0.0:
            raise ValueError(f"VirtualClock.advance: dt_s must be >= 0, got {dt_s!r}")
        with self._lock:
            self._now_s += float(dt_s)
            now = self._now_s
        self._fire_due()
        return now

    def advance_to(self, t_s: float) -> float:
        """Move time forward to ``t_s`` if it lies in the future; never moves backward."""
        with self._lock:
            if t_s > self._now_s:
                self._now_s = float(t_s)
            now = self._now_s
        self._fire_due()
        return now

    # -- timers ------------------------------------------------------------------------------
    def call_at(self, t_s: float, callback: Callable[[], None]) -> int:
        """Run ``callback()`` once the clock reaches ``t_s`` (at once if it already has).
        Returns a handle for :meth:`cancel`."""
        t = float(t_s)
        if t != t:  # NaN would never fire and never sort
            raise ValueError("VirtualClock.call_at: t_s must not be NaN")
        with self._lock:
            handle = next(self._ids)
            heapq.heappush(self._timers, (t, handle, callback))
        self._fire_due()
        return handle

    def cancel(self, handle: int) -> None:
        """Forget a timer that has not fired yet (no effect otherwise)."""
        with self._lock:
            if any(h == handle for _, h, _ in self._timers):
                self._cancelled.add(handle)

    def pending_timers(self) -> int:
        with self._lock:
            return sum(1 for _, h, _ in self._timers if h not in self._cancelled)

    def _fire_due(self) -> None:
        while True:
            with self._lock:
                if not self._timers or self._timers[0][0] > self._now_s:
                    return
                _, handle, callback = heapq.heappop(self._timers)
                if handle in self._cancelled:
                    self._cancelled.discard(handle)
                    continue
            callback()
