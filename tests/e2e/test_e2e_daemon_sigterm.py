"""SIGTERM to a REAL daemon while a real ``lidarctl scan --json`` follows a scan on it: the client
prints the scan's final record on stdout (state ``interrupted``, the points measured so far, the
signal named) and says why it failed; the daemon shuts down cleanly and exits 0; the scan's sidecar
names the shutdown as its ``stop_reason``. Every wait is on a process's output or exit, with a
deadline, never a sleep that decides."""

from __future__ import annotations

import json
import os
import signal
import subprocess

import pytest

from lidard.outputs import read_points, read_sidecar
from tests.e2e.test_e2e_cli_interrupt import _lidarctl
from tests.helpers.daemon import kill_group, start_daemon
from tests.helpers.deadlines import WAIT_S

pytestmark = pytest.mark.slow  # a real daemon and a real client


@pytest.mark.slow  # a real daemon (child bench) and a real client
def test_sigterm_to_the_daemon_mid_scan_reports_the_interrupted_scan_and_exits_0(tmp_path):
    data_dir = tmp_path / "data"
    daemon, url = start_daemon(data_dir)
    client = None
    try:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        env.pop("LIDARD_DEBUG", None)
        client = subprocess.Popen(_lidarctl() + ["scan", "--url", url, "--json", "--progress", "lines",
                                                 "--pattern", "raster", "--averages", "8", "--max-range", "2",
                                                 "--out", str(tmp_path / "cli.ply")],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        seen = []
        for line in client.stderr:                 # the client's own progress output, no sleeps
            seen.append(line)
            if line.startswith("scanning"):
                os.kill(daemon.pid, signal.SIGTERM)     # the daemon only, as systemd's stop does
                break
        out, rest = client.communicate(timeout=WAIT_S)
        daemon_code = daemon.wait(timeout=WAIT_S)
    finally:
        for p in (client, daemon):
            if p is not None and p.poll() is None:
                kill_group(p) if p is daemon else p.kill()
    err = "".join(seen) + rest
    assert any(line.startswith("scanning") for line in seen), err
    assert daemon_code == 0, daemon.stderr.read().decode(errors="replace")[-3000:]
    # the client printed the final record, then one error line naming the shutdown
    rec = json.loads(out)
    assert rec["state"] == "interrupted" and rec["partial"] is True, rec
    assert rec["points"] > 0 and 0 < rec["coverage"] < 1, rec
    assert "SIGTERM" in (rec["error"] or ""), rec
    assert client.returncode == 1, err
    assert f"scan {rec['id']} interrupted" in err.strip().splitlines()[-1], err
    # what the daemon kept: the partial points and a sidecar naming the shutdown
    ply = data_dir / "scans" / rec["id"] / "scan.ply"
    side = read_sidecar(ply)
    assert side["partial"] is True and side["stop_reason"] == "lidard shut down (SIGTERM)"
    assert len(read_points(ply)) == side["points"] == rec["points"]
