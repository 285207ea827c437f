"""What the FPSA driver is told at construction, grouped: how it talks over the link
(:class:`FpsaLink`: reply timeout, retries and their backoff, upload chunk size, the clocks it waits
and times with) and what it already knows of the chip (:class:`ChipLayout`; anything left None is
asked of the board by IDENTIFY).

Pure module: no I/O.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.errors import InvalidValue

from . import protocol as p


@dataclass(frozen=True)
class FpsaLink:
    """``timeout_s``: the longest wait for a reply (an empty read means it passed); ``retries``: how
    many times a failed command is sent again, ``backoff_s`` before the first retry (doubling, see
    :class:`drivers.retry.RetryPolicy`); ``chunk_pixels``: pixels per pattern-upload frame (halved on
    a noisy line down to a floor); ``sleep``/``monotonic``: the clock waits go through and replies are
    timed by (the simulated bench's virtual clock in tests)."""

    timeout_s: float = 0.5
    retries: int = 3
    backoff_s: float = 0.01
    chunk_pixels: int = 1024
    sleep: Callable[[float], None] = time.sleep
    monotonic: Callable[[], float] = time.monotonic

    def check(self, device: str) -> None:
        """An InvalidValue naming the first bad setting."""
        if not self.timeout_s > 0:
            raise InvalidValue(device, "configure", f"{device}: timeout_s must be > 0, got {self.timeout_s!r}")
        if not (isinstance(self.retries, int) and self.retries >= 0):
            raise InvalidValue(device, "configure", f"{device}: retries must be an int >= 0, got {self.retries!r}")
        if not self.backoff_s >= 0:
            raise InvalidValue(device, "configure", f"{device}: backoff_s must be >= 0, got {self.backoff_s!r}")
        if not 1 <= self.chunk_pixels <= p.MAX_CHUNK_PIXELS:
            raise InvalidValue(device, "configure", f"{device}: chunk_pixels must be 1..{p.MAX_CHUNK_PIXELS}")


@dataclass(frozen=True)
class ChipLayout:
    """What the caller knows of the chip, winning over what the board reports: its ``rows`` and
    ``cols`` and the rows whose switches are bonded (wired); None: asked of the board (IDENTIFY)."""

    rows: int | None = None
    cols: int | None = None
    bonded_rows: tuple[int, ...] | list[int] | range | np.ndarray | None = None


__all__ = ["ChipLayout", "FpsaLink"]
