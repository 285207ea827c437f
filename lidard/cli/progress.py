"""Scan progress on stderr, fed with the worker's events (``{"event": "progress", "stage", "fraction",
"pixels_done", "pixels_planned", "points"}`` and a final ``{"event": "end"}``, the same dicts the
daemon streams as server-sent events).

Three renderings, chosen by ``--progress``:

* ``bar``: a tqdm bar with rate and ETA, redrawn in place (the default on a terminal);
* ``lines``: one plain line per 10 % of the pixels (and one per stage change), the default when
  stderr is not a terminal, so a log file or CI output gets eleven lines, not thousands of ``\\r``;
* ``json``: one JSON object per event, for a program that drives ``lidarctl``;
* ``none``: nothing.

tqdm replaces the hand-written bar of earlier versions: it computes the rate and ETA and knows how
to redraw on narrow terminals; the lines and JSON renderings are ours because tqdm has no "one line
per decile" mode.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any, Callable, TextIO

MODES = ("auto", "bar", "lines", "json", "none")
_STEP = 10  # percent between two lines in ``lines`` mode


class Progress:
    """Callable with one worker event; ``close()`` ends the output with a newline if it drew."""

    def __init__(self, mode: str = "auto", file: TextIO | None = None, width: int = 30,
                 clock: Callable[[], float] = time.monotonic):
        if mode not in MODES:
            raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.file = file if file is not None else sys.stderr
        if mode == "auto":
            mode = "bar" if _isatty(self.file) else "lines"
        self.mode, self.width, self.clock = mode, width, clock
        self._bar = None
        self._stage: str | None = None
        self._decile = -1
        self._t0: float | None = None
        self.lines_written = 0

    def __call__(self, ev: dict[str, Any]) -> None:
        if self.mode == "none":
            return
        if self.mode == "json":
            self._write(json.dumps(ev, default=str) + "\n")
            return
        if ev.get("event") != "progress":
            return
        if self.mode == "bar":
            self._draw_bar(ev)
        else:
            self._draw_line(ev)

    # -- bar (tqdm) ------------------------------------------------------------------------------
    def _draw_bar(self, ev: dict[str, Any]) -> None:
        from tqdm import tqdm
        stage, total = str(ev.get("stage", "")), int(ev.get("pixels_planned") or 0)
        if not total:  # a stage with no pixel count (linearizing, preparing): a bar would say "0/?"
            if stage != self._stage:
                self._close_bar()
                self._stage = stage
                self._write(f"{stage}...\n")
            return
        if self._bar is None or stage != self._stage or (total and self._bar.total != total):
            self._close_bar()
            self._stage = stage
            self._bar = tqdm(total=total, file=self.file, desc=f"{stage:>11}", unit="px",
                             postfix=f"{int(ev.get('points') or 0)} pts",
                             ascii=".#", dynamic_ncols=False, leave=True, mininterval=0.1,
                             bar_format="{desc} [{bar:WIDTH}] {percentage:5.1f}% {n_fmt}/{total_fmt} px"
                                        "{postfix}  ETA {remaining}, {rate_fmt}".replace("WIDTH", str(self.width)))
        self._bar.set_postfix_str(f"{int(ev.get('points') or 0)} pts", refresh=False)
        done = int(ev.get("pixels_done") or 0)
        if done > self._bar.n:
            self._bar.update(done - self._bar.n)
        else:
            self._bar.refresh()

    def _close_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # -- lines -----------------------------------------------------------------------------------
    def _draw_line(self, ev: dict[str, Any]) -> None:
        stage = str(ev.get("stage", ""))
        if stage != self._stage:
            self._stage, self._decile, self._t0 = stage, -1, self.clock()
            if stage != "scanning":
                self._write(f"{stage}...\n")
        planned = int(ev.get("pixels_planned") or 0)
        if not planned:
            return
        frac = min(max(float(ev.get("fraction") or 0.0), 0.0), 1.0)
        decile = int(frac * 100 + 1e-9) // _STEP
        if decile <= self._decile or decile == 0:
            return
        self._decile = decile
        elapsed = self.clock() - (self._t0 or self.clock())
        eta = f", ETA {elapsed * (1 - frac) / frac:.0f} s" if 0 < frac < 1 else ""
        self._write(f"{stage} {decile * _STEP:3d} %  {ev.get('pixels_done', 0)}/{planned} px  "
                    f"{ev.get('points', 0)} pts{eta}\n")

    def _write(self, text: str) -> None:
        self.file.write(text)
        self.file.flush()
        self.lines_written += 1

    def close(self) -> None:
        self._close_bar()


def _isatty(f: TextIO) -> bool:
    try:
        return f.isatty()
    except (AttributeError, ValueError):
        return False
