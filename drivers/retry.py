"""The one retry policy of every bounded retry loop: how many tries, the backoff between them, and
whose clock waits.

A loop asks the policy for its tries (``for attempt in policy.tries():``) and keeps its own
judgement of each failure (re-send, reconnect, give up); :meth:`RetryPolicy.call` is the whole loop
for a plain "try again on these errors". Backoff is exponential: ``backoff_s`` before the second
try, doubling after each (a device that is busy or re-enumerating is given ever more time, and the
total wait stays bounded: ``backoff_s * (2**(attempts-1) - 1)``). The wait goes through the
injected ``sleep``: ``time.sleep`` in the lab, the simulated bench's ``VirtualClock.advance``, so a
retry never costs wall-clock time on the bench and tests need no real waiting.

Pure module: no I/O, importable by drivers and the daemon alike.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TypeVar

from drivers.errors import InvalidValue

T = TypeVar("T")


@dataclass(frozen=True)
class RetryPolicy:
    """``attempts`` tries in all (1: no retry), ``backoff_s`` before the second (doubling), waited
    through ``sleep``; :meth:`call` retries the errors of ``retry_on``."""

    attempts: int
    backoff_s: float = 0.0
    sleep: Callable[[float], object] = time.sleep
    retry_on: tuple[type[BaseException], ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.attempts, bool) or not isinstance(self.attempts, int) or self.attempts < 1:
            raise InvalidValue("retry", "configure", f"attempts must be an int >= 1, got {self.attempts!r}")
        if not (isinstance(self.backoff_s, (int, float)) and math.isfinite(self.backoff_s) and self.backoff_s >= 0):
            raise InvalidValue("retry", "configure", f"backoff_s must be a finite number >= 0, got {self.backoff_s!r}")
        if not callable(self.sleep):
            raise InvalidValue("retry", "configure", f"sleep must be callable, got {self.sleep!r}")

    @classmethod
    def retries(cls, retries: int, backoff_s: float = 0.0, sleep: Callable[[float], object] = time.sleep,
                retry_on: tuple[type[BaseException], ...] = ()) -> RetryPolicy:
        """The policy of a loop configured by its number of RE-tries (``retries + 1`` attempts)."""
        return cls(int(retries) + 1, float(backoff_s), sleep, retry_on)

    def delay_s(self, retry: int) -> float:
        """The wait before retry number ``retry`` (1 = the second attempt)."""
        return float(self.backoff_s * 2 ** (retry - 1)) if retry >= 1 else 0.0

    def tries(self) -> Iterator[int]:
        """The attempt numbers 0 .. attempts - 1, waiting :meth:`delay_s` before each retry (a zero
        wait is not slept)."""
        for attempt in range(self.attempts):
            if attempt:
                delay = self.delay_s(attempt)
                if delay > 0:
                    self.sleep(delay)
            yield attempt

    def call(self, fn: Callable[[], T], *, on_retry: Callable[[int, BaseException], object] | None = None) -> T:
        """``fn()``, tried again on the errors of ``retry_on`` (``on_retry(attempt, error)`` after each
        failed try that will be retried); the last error propagates when the tries run out."""
        for attempt in self.tries():
            try:
                return fn()
            except self.retry_on as exc:
                if attempt == self.attempts - 1:
                    raise
                if on_retry is not None:
                    on_retry(attempt, exc)
        raise AssertionError("unreachable: the last try returns or raises")
