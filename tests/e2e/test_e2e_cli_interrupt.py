"""Ctrl-C on a real ``lidarctl scan --sim`` process: it exits 130 and keeps the points measured so far
(the file and a sidecar that says partial). The signal is sent after the first scanning progress line
is read from the process's stderr, so the test waits on the program's own output, not on a sleep."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from lidard.pointcloud import read_points, read_sidecar

REPO = Path(__file__).resolve().parents[2]


def _lidarctl() -> list[str]:
    script = Path(sys.executable).with_name("lidarctl")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "import sys; from lidard.cli import lidarctl_main; sys.exit(lidarctl_main())"]


@pytest.mark.slow  # a real process: bench start and chirp linearization first (~10 s on an idle machine)
def test_sigint_after_first_progress_line_exits_130_with_partial_points(tmp_path):
    out_file = tmp_path / "part.ply"
    cmd = _lidarctl() + ["scan", "--sim", "--scene", str(REPO / "config/scenes/cal_letters.toml"),
                         "--rows", "0:64", "--out", str(out_file), "--progress", "lines"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("LIDARD_DEBUG", None)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    seen = []
    try:
        for line in p.stderr:                      # blocks on the program's output, no sleeps
            seen.append(line)
            if line.startswith("scanning"):
                p.send_signal(signal.SIGINT)
                break
        out, rest = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    err = "".join(seen) + rest
    assert any(line.startswith("scanning") for line in seen), err
    assert p.returncode == 130, err
    assert "interrupted" in err.strip().splitlines()[-1] and "points kept" in err
    side = read_sidecar(out_file)
    pts = read_points(out_file)
    assert side["partial"] is True and side["points"] == len(pts) > 0
    assert 0 < side["pixels_scanned"] < side["pixels_planned"]
    assert "cancelled (partial)" in out
