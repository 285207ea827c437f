"""One process per data directory: the store's OS lock (flock), with real processes."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap

import pytest

from tests.helpers.deadlines import WAIT_S
from lidard.store import LOCK_NAME, DataDirLocked, Store

_HOLDER = textwrap.dedent("""
    import sys
    from lidard.store import Store
    s = Store(sys.argv[1])
    rec = s.create_scan({"pattern": "raster"})
    s.transition(rec.id, ("queued",), state="running")
    print(rec.id, flush=True)
    sys.stdin.read()          # hold the directory until the parent closes our stdin or kills us
""")


def _state(data_dir, scan_id: str) -> str:
    with sqlite3.connect(f"file:{data_dir / 'lidard.sqlite3'}?mode=ro", uri=True) as db:
        return db.execute("SELECT state FROM scans WHERE id=?", (scan_id,)).fetchone()[0]


@pytest.fixture
def holder(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(tmp_path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    scan_id = proc.stdout.readline().strip()
    assert scan_id, "the holder process did not start"
    yield proc, scan_id
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=WAIT_S)


def test_second_process_is_refused_naming_the_holder(tmp_path, holder):
    proc, scan_id = holder
    with pytest.raises(DataDirLocked) as err:
        Store(tmp_path)
    assert f"PID {proc.pid}" in str(err.value) and str(tmp_path) in str(err.value)
    # the refused process changed nothing: the holder's scan is still running
    assert _state(tmp_path, scan_id) == "running"


def test_next_holder_after_kill_9_marks_the_running_scan_interrupted(tmp_path, holder):
    proc, scan_id = holder
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=WAIT_S)
    store = Store(tmp_path)           # the kernel released the dead holder's lock
    try:
        assert store.recovered == 1
        assert store.get_scan(scan_id).state == "interrupted"
        assert (tmp_path / LOCK_NAME).read_text().strip() == str(os.getpid())
    finally:
        store.close()


def test_close_releases_the_directory(tmp_path):
    first = Store(tmp_path)
    with pytest.raises(DataDirLocked, match=f"PID {os.getpid()}"):
        Store(tmp_path)
    first.close()
    Store(tmp_path).close()


@pytest.mark.parametrize("argv", [
    ["-m", "lidard", "--config", "config/sim.toml", "--port", "0"],
    ["-c", "import sys; from lidard.cli import lidarctl_main; sys.exit(lidarctl_main())", "scan", "--sim", "--rows", "0:2", "--cols", "0:2", "--out", "x.ply"],
], ids=["lidard", "lidarctl-scan-sim"])
def test_held_directory_refuses_daemon_and_one_shot_scan(tmp_path, holder, argv):
    from pathlib import Path
    proc, _ = holder
    repo = Path(__file__).resolve().parents[3]
    out = subprocess.run([sys.executable, *argv, "--data-dir", str(tmp_path)], cwd=repo,
                         capture_output=True, text=True, timeout=WAIT_S, stdin=subprocess.DEVNULL)
    assert out.returncode != 0
    assert f"PID {proc.pid}" in out.stderr and "in use by another lidard process" in out.stderr
    assert "serving on" not in out.stderr     # refused before binding a bench or serving
