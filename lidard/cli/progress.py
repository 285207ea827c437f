"""Scan progress on stderr, fed with the worker's events (``{"event": "progress", "stage", "fraction",
"pixels_done", "pixels_planned", "points"}`` and a final ``{"event": "end"}``, the same dicts the
daemon streams as server-sent events).

Three renderings, chosen by ``--progress``:

* ``bar``: a tqdm bar with rate and ETA, redrawn in place (the default on a terminal);
* ``lines``: one plain line per 10 % of the pixels (and one per stage change), the default when
  stderr is not a terminal, so a log file or CI output gets eleven lines, not thousands of ``\\r``;
* ``json``: one JSON object per event, for a program that drives ``lidarctl``;
* ``none``: nothing.

tqdm replaces the hand-written bar of earlier versions: it knows how to redraw on narrow terminals;
the lines and JSON renderings are ours because tqdm has no "one line per decile" mode.

The ETA counts scanning only: its rate is measured from the first report of the scanning stage that
has pixels done (the linearization, the health check and the first batch's set-up are not in it), as
pixels per second since then. A stage without a pixel count (linearizing) says its steps instead
(``linearizing: measurement N``), so a long linearization is not a silent ``linearizing...``.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any, TextIO
from collections.abc import Callable

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
        self._bar: Any = None   # the stage's tqdm bar
        self._stage: str | None = None
        self._decile = -1
        self._rate_from: tuple[float, int] | None = None    # (clock, pixels done) of the stage's first report
        self._steps = 0
        self.lines_written = 0

    def eta_s(self, ev: dict[str, Any]) -> float | None:
        """Seconds left in this stage at ``ev``: the pixels to go at the rate measured since the stage's
        first report with pixels done (None until a second report has moved on from it)."""
        done, total = int(ev.get("pixels_done") or 0), int(ev.get("pixels_planned") or 0)
        now = self.clock()
        if self._rate_from is None:
            if done > 0:
                self._rate_from = (now, done)
            return None
        t1, n1 = self._rate_from
        if done <= n1 or now <= t1:
            return None
        return (total - done) * (now - t1) / (done - n1)

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
                self._stage, self._steps = stage, 0
                self._write(f"{stage}...\n")
            self._step_line(stage, ev)
            return
        if self._bar is None or stage != self._stage or (total and self._bar.total != total):
            self._close_bar()
            self._stage, self._rate_from = stage, None
            self._bar = tqdm(total=total, file=self.file, desc=f"{stage:>11}", unit="px",
                             postfix=f"{int(ev.get('points') or 0)} pts",
                             ascii=".#", dynamic_ncols=False, leave=True, mininterval=0.1,
                             bar_format="{desc} [{bar:WIDTH}] {percentage:5.1f}% {n_fmt}/{total_fmt} px"
                                        "{postfix}".replace("WIDTH", str(self.width)))
        eta = self.eta_s(ev)
        bar = self._bar
        bar.set_postfix_str(f"{int(ev.get('points') or 0)} pts  ETA "
                                  f"{'?' if eta is None else _duration(eta)}", refresh=False)
        done = int(ev.get("pixels_done") or 0)
        if done > bar.n:
            bar.update(done - bar.n)
        else:
            bar.refresh()

    def _close_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # -- lines -----------------------------------------------------------------------------------
    def _draw_line(self, ev: dict[str, Any]) -> None:
        stage = str(ev.get("stage", ""))
        if stage != self._stage:
            self._stage, self._decile, self._rate_from, self._steps = stage, -1, None, 0
            if stage != "scanning":
                self._write(f"{stage}...\n")
        planned = int(ev.get("pixels_planned") or 0)
        if not planned:
            self._step_line(stage, ev)
            return
        eta_s = self.eta_s(ev)
        frac = min(max(float(ev.get("fraction") or 0.0), 0.0), 1.0)
        decile = int(frac * 100 + 1e-9) // _STEP
        if decile <= self._decile or decile == 0:
            return
        self._decile = decile
        eta = f", ETA {eta_s:.{1 if eta_s < 10 else 0}f} s" if eta_s is not None and frac < 1 else ""
        self._write(f"{stage} {decile * _STEP:3d} %  {ev.get('pixels_done', 0)}/{planned} px  "
                    f"{ev.get('points', 0)} pts{eta}\n")

    def _step_line(self, stage: str, ev: dict[str, Any]) -> None:
        """``linearizing: measurement N`` for each new step a stage without pixels reports."""
        n = ev.get("measurements")
        if n is not None and int(n) > self._steps:
            self._steps = int(n)
            self._write(f"{stage}: measurement {self._steps}\n")

    def _write(self, text: str) -> None:
        self.file.write(text)
        self.file.flush()
        self.lines_written += 1

    def close(self) -> None:
        self._close_bar()


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 60 else f"{int(s // 60)} min {round(s % 60):02d} s"


def _isatty(f: TextIO) -> bool:
    try:
        return f.isatty()
    except (AttributeError, ValueError):
        return False
