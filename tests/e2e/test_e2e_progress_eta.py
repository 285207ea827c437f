"""Honest progress on the simulated bench's virtual clock: a cold one-shot scan linearizes (and says
each measurement), then scans; the ETA printed from 10 % on is within +-30 % of the scanning time
actually left (the linearization and the health check before it are not in its rate)."""

import io
import re
import threading
from types import SimpleNamespace

import pytest

from lidard.cli.embedded import embedded
from lidard.cli.progress import Progress
from lidard.config import CONFIG_DIR
from lidard.jobs import request_from_dict

pytestmark = pytest.mark.slow


class _Log(io.StringIO):
    """stderr of the progress, each line stamped with the clock at which it was written."""

    def __init__(self, clock):
        super().__init__()
        self.clock, self.stamped = clock, []

    def write(self, s):
        self.stamped.append((self.clock(), s))
        return super().write(s)


def test_the_eta_counts_scanning_only_and_holds_from_ten_percent(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))      # cold: the scan linearizes first
    args = SimpleNamespace(config=str(CONFIG_DIR / "sim.toml"), profile=None, data_dir=None, no_cal_cache=None)
    with embedded(args) as (worker, store, inst):
        clock = inst._on_close.__self__.clock.now                       # the bench's virtual time
        log = _Log(clock)
        prog = Progress("lines", file=log, clock=clock)
        end = threading.Event()
        rec = worker.submit_scan(request_from_dict({"pattern": "roi", "rows": [40, 72], "cols": [0, 64],
                                                    "averages": 10}))
        unsub = worker.subscribe(rec.id, lambda ev: (prog(ev), end.set() if ev.get("event") == "end" else None))
        final = worker.wait(rec.id)
        unsub()
    assert final.state == "done", final.error
    lines = log.stamped
    text = "".join(s for _, s in lines)
    assert text.startswith("linearizing...\n") and re.search(r"linearizing: measurement \d+\n", text), text
    scan_lines = [(t, s) for t, s in lines if s.startswith("scanning ")]
    t_end = scan_lines[-1][0]                           # the 100 % line: the last pixel read
    checked = 0
    for t, s in scan_lines[:-1]:
        m = re.search(r"ETA (\d+(?:\.\d)?) s", s)
        if m is None:
            continue
        left = t_end - t
        assert abs(float(m.group(1)) - left) <= 0.3 * left + 0.05, (s, left)    # + the printed rounding
        checked += 1
    assert checked >= 7, text       # 20 % .. 90 % at least (10 % may come before a second report)
