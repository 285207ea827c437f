"""benchmarks/child_bench_cost.py: the per-scan CPU and memory of a real lidar-sim child."""

from __future__ import annotations

import os
import sys
import time

import numpy as np
import pytest

from benchmarks import child_bench_cost

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def test_process_figures_follow_the_process():
    before = child_bench_cost.process_figures(os.getpid())
    block = np.ones(64 << 20, np.uint8)              # 64 MiB touched: resident and anonymous
    t0 = time.process_time()
    while time.process_time() - t0 < 0.2:             # CPU spent, not a wait
        block[::4096] += 1
    after = child_bench_cost.process_figures(os.getpid())
    assert after["rss_mb"] - before["rss_mb"] >= 60 and after["anon_mb"] - before["anon_mb"] >= 60
    assert (after["user_s"] + after["system_s"]) - (before["user_s"] + before["system_s"]) >= 0.1
    del block


@pytest.mark.parametrize("argv", [["--scans", "3", "--skip", "2"], ["--skip", "-1"]])
def test_bad_counts_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        child_bench_cost.main(argv)
    assert exc.value.code == 2 and "--scans must be at least" in capsys.readouterr().err


@pytest.mark.slow  # a lidar-sim child and three scans
def test_a_short_run_reports_every_scan_done():
    res = child_bench_cost.run(3, 0)
    assert res["states"] == ["done"] and res["measured_scans"] == 2
    assert res["bench_user_s_per_scan"] > 0 and res["bench_rss_mb"] > 50


@pytest.mark.parametrize("argv, scan", [(["--region"], child_bench_cost.REGION), ([], child_bench_cost.SCAN)])
def test_region_flag_selects_the_larger_scan(argv, scan, monkeypatch, capsys):
    seen = []
    monkeypatch.setattr(child_bench_cost, "run", lambda scans, skip, s, idle: seen.append(s) or {"scans": scans})
    assert child_bench_cost.main(["--scans", "4", *argv]) == 0
    assert seen == [scan]
    # the region reads every column of its rows at 10 averages: larger reads than the soak's ROI
    assert (scan["cols"] == (0, 128) and scan["averages"] == 10) == bool(argv)


def test_a_bad_idle_time_is_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        child_bench_cost.main(["--idle-s", "-1"])
    assert exc.value.code == 2 and "--idle-s must be" in capsys.readouterr().err
