"""lidarctl reprocess on Dask (issue 17, item 1): the same cloud point for point, several scans, the extra.

The cluster is an in-process LocalCluster (``processes=False``, two worker threads) reached through
``--scheduler``: the same scheduler, futures and pickling of the chunk tasks as remote workers, without
the cost of spawning processes.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from lidard.cli import base as cli_base
from lidard.outputs import read_points
from lidard.raw import ReprocessSettings, reprocess
from lidard.raw.replay import chunk_count
from tests.helpers.raw_capture import RecordingFake
from tests.helpers.cli import run

pytest.importorskip("distributed")



def _record(capsys, data, cols="0:12") -> str:
    code, out, err = run(capsys, "scan", "--sim", "--data-dir", str(data), "--rows", "0:2", "--cols", cols,
                         "--record-raw", "--json", "--progress", "none")
    assert code == 0, err
    return json.loads(out)["id"]


@pytest.fixture
def data(capsys, monkeypatch, tmp_path):
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: RecordingFake())
    return tmp_path / "data"


@pytest.fixture(scope="module")
def scheduler():
    from lidard.offline.cluster import open_client
    with open_client(n_workers=2, processes=False) as c:
        yield c.scheduler.address


def _raw(data, sid):
    return data / "scans" / sid / "raw.zarr"


def test_two_dask_workers_equal_in_process_point_for_point(capsys, data, scheduler, tmp_path):
    sid = _record(capsys, data)
    assert chunk_count(_raw(data, sid)) == 3           # 24 pixels in chunks of 8: three tasks
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), "--scheduler", scheduler,
                         "--out", str(tmp_path / "dask.npz"), "--progress", "lines")
    assert code == 0, err
    assert f"dask scheduler {scheduler}" in err and f"(dask scheduler {scheduler})" in out
    assert "100 %" in err and "24/24 px" in err        # the CLI progress saw every chunk
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), "--in-process",
                         "--out", str(tmp_path / "local.npz"), "--json")
    assert code == 0, err
    assert json.loads(out)["executor"] == "in-process"
    dask_pts, local_pts = read_points(tmp_path / "dask.npz"), read_points(tmp_path / "local.npz")
    ref = reprocess(_raw(data, sid)).points            # the library path with the builtin map
    assert len(ref) > 0 and np.array_equal(dask_pts, ref) and np.array_equal(local_pts, ref)


def test_several_scans_with_the_same_settings_share_one_cluster(capsys, data, scheduler):
    a, b = _record(capsys, data), _record(capsys, data, cols="0:9")
    code, out, err = run(capsys, "reprocess", a, b, "--data-dir", str(data), "--same-settings",
                         "--estimator", "quinn2", "--pfa", "1e-4", "--scheduler", scheduler, "--json",
                         "--progress", "none")
    assert code == 0, err
    got = json.loads(out)
    assert [g["reprocessed_from"] for g in got] == [a, b]
    assert err.count("reprocessing 2 scan(s)") == 1    # one client for both
    settings = ReprocessSettings(estimator="quinn2", pfa=1e-4)
    for g, sid in zip(got, (a, b)):
        assert g["executor"] == f"dask scheduler {scheduler}"
        assert g["points"] == len(reprocess(_raw(data, sid), settings).points)


def test_several_scans_need_same_settings(capsys, data):
    code, out, err = run(capsys, "reprocess", "A", "B", "--data-dir", str(data))
    assert code != 0 and "--same-settings" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("argv, needle", [
    (["reprocess", "X", "--scheduler", "tcp://h:8786"], "works offline only"),
    (["reprocess", "X", "--in-process", "--dask", "--data-dir", "/d"], "--in-process contradicts --dask"),
    (["reprocess", "X", "--workers", "0", "--data-dir", "/d"], "--workers must be at least 1"),
    (["reprocess", "X", "--scheduler", "tcp://h:1", "--workers", "2", "--data-dir", "/d"], "leave out --dask"),
])
def test_flag_errors(capsys, argv, needle):
    code, out, err = run(capsys, *argv)
    assert code != 0 and needle in err and len(err.strip().splitlines()) == 1


def test_missing_extra_names_the_install_command_and_default_stays_in_process(capsys, data, monkeypatch):
    sid = _record(capsys, data)
    monkeypatch.setitem(sys.modules, "distributed", None)      # find_spec() now says: not installed
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), "--workers", "2")
    assert code != 0 and "missing: distributed" in err and 'pip install -e ".[offline]"' in err
    # without a Dask flag the default falls back to this process and says so
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), "--json", "--progress", "none")
    assert code == 0, err
    assert json.loads(out)["executor"] == "in-process"
    assert "reprocessing 1 scan(s): in-process" in err


@pytest.mark.parametrize("flags, workers", [(["--workers", "2"], 2), (["--dask"], None)])
def test_dask_and_workers_start_a_local_cluster_of_processes(capsys, data, monkeypatch, flags, workers):
    """--dask/--workers ask open_client for a LocalCluster of processes (here swapped for threads)."""
    import os

    from lidard.offline import cluster
    sid = _record(capsys, data)
    asked, real = [], cluster.open_client
    def fake_open_client(scheduler=None, **kw):
        asked.append((scheduler, kw["n_workers"], kw["processes"]))
        return real(n_workers=kw["n_workers"], processes=False)
    monkeypatch.setattr(cluster, "open_client", fake_open_client)
    code, out, err = run(capsys, "reprocess", sid, "--data-dir", str(data), *flags, "--json", "--progress", "none")
    assert code == 0, err
    n = workers or os.cpu_count()
    assert asked == [(None, n, True)]
    assert json.loads(out)["executor"] == f"dask LocalCluster ({n} worker processes)"
