"""lidarctl scan --record-raw, reprocess and spectrum: offline on a data directory and through a daemon."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidard.cli import base as cli_base
from lidard.outputs import read_points, read_sidecar
from lidard.raw import ReprocessSettings, reprocess
from tests.helpers.api import live_server, make_app
from tests.helpers.raw_capture import RecordingFake
from tests.helpers.cli import run



@pytest.fixture
def recorded(capsys, monkeypatch, tmp_path):
    """A data directory with one scan recorded through `lidarctl scan --sim --record-raw`."""
    made = []
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: made.append(RecordingFake()) or made[-1])
    data = tmp_path / "data"
    code, out, err = run(capsys, "scan", "--sim", "--data-dir", str(data), "--rows", "0:2", "--cols", "0:12",
                         "--record-raw", "--out", str(tmp_path / "orig.npz"), "--json", "--progress", "none")
    assert code == 0, err
    sid = json.loads(out)["id"]
    assert made[0].requests[0].record_raw is True and (data / "scans" / sid / "raw.zarr" / "zarr.json").is_file()
    return data, sid, tmp_path


@pytest.mark.slow  # a reprocessing through a local Dask cluster (~20 s)
def test_reprocess_offline_reproduces_the_scan_and_links_it(capsys, recorded):
    data, sid, tmp = recorded
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), "--out", str(tmp / "again.npz"), "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["reprocessed_from"] == sid and s["state"] == "done" and s["out"] == str(tmp / "again.npz")
    assert s["executor"].startswith("dask LocalCluster")   # the default: 3 chunks and the extra installed
    assert np.array_equal(read_points(tmp / "again.npz"), read_points(tmp / "orig.npz"))
    assert read_sidecar(tmp / "again.npz")["reprocessed_from"] == sid


def test_reprocess_offline_with_overrides(capsys, recorded):
    data, sid, tmp = recorded
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), "--estimator", "quinn2", "--pfa", "1e-4",
                         "--window", "blackmanharris", "--out", str(tmp / "q.npz"), "--in-process")
    assert code == 0, err and "reprocessed from" in out
    ref = reprocess(data / "scans" / sid / "raw.zarr",
                    ReprocessSettings(estimator="quinn2", pfa=1e-4, window="blackmanharris")).points
    got = read_points(tmp / "q.npz")
    # the same points, flags and pixels; values to the agreement the compiled joint fit states
    # against numpy (lidard/dsp/spectrum/_kernels_fit.py: ~1e-8 bin), whichever ran in each path
    assert got.dtype == ref.dtype and len(got) == len(ref)
    for name in ref.dtype.names:
        if ref.dtype[name].kind == "f":
            np.testing.assert_allclose(got[name], ref[name], rtol=1e-9, atol=1e-9, err_msg=name)
        else:
            assert np.array_equal(got[name], ref[name]), name
    side = read_sidecar(tmp / "q.npz")
    assert side["dsp"]["estimator"] == "quinn2" and side["dsp"]["window"] == "blackmanharris"


def test_spectrum_offline_text_json_and_plot(capsys, recorded):
    data, sid, tmp = recorded
    png = tmp / "px.png"
    code, out, err = run(capsys, "spectrum", sid, "--data-dir", str(data), "--pixel", "1,3", "--plot", str(png))
    assert code == 0, err
    assert "pixel (1, 3)" in out and "RANGE_M" in out and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code, out, err = run(capsys, "spectrum", sid, "--data-dir", str(data), "--pixel", "1,3", "--json")
    d = json.loads(out)
    assert d["row"] == 1 and d["col"] == 3 and d["detections"] and d["points"]


@pytest.mark.parametrize("argv, needle", [
    (["reprocess", "X", "--data-dir", "/nonexistent/d"], "not a lidard data directory"),
    (["spectrum", "X", "--data-dir", "/nonexistent/d", "--pixel", "1"], "--pixel: expected ROW,COL"),
    (["reprocess", "X", "--pfa", "0.5", "--data-dir", "/nonexistent/d"], "pfa=0.5 must lie"),
    (["reprocess", "X", "--estimator", "fft"], "--estimator"),
])
def test_errors_are_one_line(capsys, argv, needle):
    code, out, err = run(capsys, *argv)
    assert code != 0 and needle in err and len(err.strip().splitlines()) == 1


def test_through_a_daemon(capsys, tmp_path):
    inst = RecordingFake()
    app = make_app(tmp_path / "data", inst, progress_interval_s=0.0)
    with live_server(app) as url:
        code, out, err = run(capsys, "scan", "--url", url, "--rows", "0:2", "--cols", "0:8", "--record-raw",
                             "--out", str(tmp_path / "o.npz"), "--json", "--progress", "none")
        assert code == 0, err
        sid = json.loads(out)["id"]
        code, out, err = run(capsys, "reprocess", sid, "--url", url, "--out", str(tmp_path / "r.npz"), "--json")
        assert code == 0, err
        new_id = json.loads(out)["id"]
        assert json.loads(out)["reprocessed_from"] == sid
        code, out, err = run(capsys, "scans", "show", sid, "--url", url)
        raw_line = [ln for ln in out.splitlines() if ln.startswith("raw capture")]
        assert code == 0 and raw_line and raw_line[0].endswith(" MB")
        code, out, err = run(capsys, "scans", "show", new_id, "--url", url)
        assert any(ln.startswith("reprocessed from") and ln.endswith(sid) for ln in out.splitlines())
        assert np.array_equal(read_points(tmp_path / "r.npz"), read_points(tmp_path / "o.npz"))
        code, out, err = run(capsys, "spectrum", sid, "--url", url, "--pixel", "0,2", "--plot", str(tmp_path / "s.png"))
        assert code == 0, err and "pixel (0, 2)" in out and (tmp_path / "s.png").is_file()
        code, out, err = run(capsys, "spectrum", sid, "--url", url, "--pixel", "40,2")
        assert code == 1 and "404" in err and "was not recorded" in err


def test_the_cli_and_the_api_offer_exactly_the_dsps_estimators_and_windows():
    from typing import get_args

    from lidard.api import schemas
    from lidard.cli import raw as cli_raw
    from lidard.dsp.ranging.estimators import EstimatorName
    from lidard.dsp.spectrum.window import WindowName
    assert cli_raw.ESTIMATORS == get_args(EstimatorName) == get_args(schemas.EstimatorName)
    assert cli_raw.WINDOWS == get_args(WindowName) == get_args(schemas.WindowName)
