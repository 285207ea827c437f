"""A REAL daemon process for end-to-end tests: ``python -m lidard --config config/sim.toml`` on a free
port with a given data directory, in its own process group (so the child bench goes with it).

All waiting is bounded polling with deadlines, never a sleep that decides.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from collections.abc import Callable

import httpx
import pytest

from tests.helpers.deadlines import STARTUP_S

REPO = Path(__file__).resolve().parents[2]


def start_daemon(data_dir: Path, *, env: dict[str, str] | None = None) -> tuple[subprocess.Popen, str]:
    """Start the daemon; answers the process and its base URL once /health answers 200."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "lidard", "--config", str(REPO / "config" / "sim.toml"), "--port", "0",
         "--data-dir", str(data_dir), "--log-level", "warning"],
        cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}, stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + STARTUP_S
    lines: list[str] = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline().decode(errors="replace")
        if not line:
            if proc.poll() is not None:
                break
            continue
        lines.append(line)
        m = re.search(r"serving on (http://[\d.]+:\d+)", line)
        if m:
            url = m.group(1)
            # the socket is bound before uvicorn starts: wait for the app to answer
            while time.monotonic() < deadline:
                try:
                    if httpx.get(url + "/health", timeout=2.0).status_code == 200:
                        return proc, url
                except httpx.TransportError:
                    time.sleep(0.05)   # polling interval only; the deadline decides
            break
    kill_group(proc)
    pytest.fail("lidard did not come up: " + "".join(lines[-20:]))


def kill_group(proc: subprocess.Popen) -> None:
    """kill -9 the daemon's whole process group (the bench child too) and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=30)
    if proc.stderr:
        proc.stderr.close()


def stop_daemon(proc: subprocess.Popen) -> None:
    """SIGTERM (a clean shutdown: outputs down, store closed), then SIGKILL if it does not end."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        kill_group(proc)
        return
    if proc.stderr:
        proc.stderr.close()


def poll(fn: Callable[[], object], timeout_s: float, what: str):
    """``fn()`` until it answers something truthy; fails the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = fn()
        if got:
            return got
        time.sleep(0.05)       # polling interval only; the deadline decides
    pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
