"""Ctrl-C, SIGTERM and SIGHUP on a real ``lidarctl scan --sim`` process: it exits 128 + the signal's
number (130, 143, 129), keeps the points measured so far (the file and a sidecar that says partial and
names the signal as its ``stop_reason``), says so on stderr and removes its temporary store. The signal
is sent after the first scanning progress line is read from the process's stderr, so the test waits on
the program's own output, not on a sleep.

The child starts with the default action for the three signals: a test run under ``nohup`` or in a
background job inherits SIGINT (and SIGHUP) ignored, and Python then never raises KeyboardInterrupt."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from lidard.outputs import read_points, read_sidecar

pytestmark = pytest.mark.slow  # real lidarctl processes, each starting and linearizing a bench

REPO = Path(__file__).resolve().parents[2]

# exec the command with SIGINT, SIGTERM and SIGHUP at their default actions (an ignored signal stays
# ignored across exec, so setting them in this small launcher is enough)
_DEFAULT_SIGNALS = ("import os, signal, sys\n"
                    "for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):\n"
                    "    signal.signal(s, signal.SIG_DFL)\n"
                    "os.execv(sys.argv[1], sys.argv[1:])\n")


def _lidarctl() -> list[str]:
    script = Path(sys.executable).with_name("lidarctl")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "import sys; from lidard.cli import lidarctl_main; sys.exit(lidarctl_main())"]


def with_default_signals(cmd: list[str]) -> list[str]:
    """``cmd`` started with the three stop signals at their default actions."""
    import shutil
    exe = cmd[0] if os.path.isabs(cmd[0]) else shutil.which(cmd[0])
    return [sys.executable, "-c", _DEFAULT_SIGNALS, exe, *cmd[1:]]


@pytest.fixture(scope="module")
def shared_calibration_cache(tmp_path_factory):
    """One calibration cache ($XDG_CACHE_HOME) for the three signals: the first process linearizes its
    bench and caches the result (lidard.calcache), the next two start scanning from the cache. What is
    tested (the signal's handling mid-scan) does not depend on who linearized."""
    return tmp_path_factory.mktemp("xdg-cache-interrupt")


@pytest.mark.slow  # a real process: bench start (and the first one's linearization, ~10 s idle)
@pytest.mark.parametrize("sig, code, words", [(signal.SIGINT, 130, "interrupted by SIGINT (Ctrl-C)"),
                                              (signal.SIGTERM, 143, "interrupted by SIGTERM"),
                                              (signal.SIGHUP, 129, "interrupted by SIGHUP")])
def test_stop_signal_after_first_progress_line_keeps_partial_points(tmp_path, shared_calibration_cache, sig,
                                                                    code, words):
    out_file = tmp_path / "part.ply"
    tmp = tmp_path / "tmp"          # the child's system temp folder: where its temporary store goes
    tmp.mkdir()
    cmd = _lidarctl() + ["scan", "--sim", "--scene", str(REPO / "config/scenes/cal_letters.toml"),
                         "--rows", "0:64", "--out", str(out_file), "--progress", "lines"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "TMPDIR": str(tmp), "XDG_CACHE_HOME": str(shared_calibration_cache)}
    env.pop("LIDARD_DEBUG", None)
    p = subprocess.Popen(with_default_signals(cmd), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=env, cwd=tmp_path)
    seen = []
    stores = []
    try:
        for line in p.stderr:                      # blocks on the program's output, no sleeps
            seen.append(line)
            if line.startswith("scanning"):
                stores = sorted(x.name for x in tmp.glob("lidarctl-*"))
                p.send_signal(sig)
                break
        out, rest = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    err = "".join(seen) + rest
    assert any(line.startswith("scanning") for line in seen), err
    assert p.returncode == code, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("lidarctl: interrupted") and "points kept" in last, err
    if sig != signal.SIGINT:
        assert f"by {signal.Signals(sig).name}" in last
    assert "cancelled (partial)" in out
    side = read_sidecar(out_file)
    pts = read_points(out_file)
    assert side["partial"] is True and side["points"] == len(pts) > 0
    assert 0 < side["pixels_scanned"] < side["pixels_planned"]
    assert side["stop_reason"] == words
    # the temporary store existed while the scan ran, and is gone
    assert len(stores) == 1, stores
    assert not list(tmp.glob("lidarctl-*"))
