"""A sweep end to end on an in-process LocalCluster: the Parquet rows, a failing configuration reported
with its parameters while the rest finish, a restart that skips finished tasks, Dask == in-process."""

from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest

from lidard.offline.results import read_results
from lidard.offline.runner import run_sweep
from lidard.offline.spec import expand_sweep
from lidard.offline.sweep import run_task

DETERMINISTIC = ["task_key", "config_hash", "detected", "false_alarms", "range_err_sum_m",
                 "range_err_sq_sum_m2", "velocity_err_sq_sum", "amplitude_v", "sample_rate_hz"]


def test_a_sweep_of_8_tasks_writes_its_parquet_rows(client, make_sweep, tmp_path):
    sw = expand_sweep(make_sweep({"link.tx_power_w": [1e-3, 1e-2]}))
    assert len(sw.tasks) == 8
    out = run_sweep(sw, tmp_path / "a", client=client)
    assert (out.total, out.skipped, out.ran, out.failures) == (8, 0, 8, [])
    table = read_results(tmp_path / "a")
    assert table.num_rows == 8
    rows = table.to_pylist()
    assert {r["task_key"] for r in rows} == {t.key for t in sw.tasks}
    by_key = {t.key: t for t in sw.tasks}
    for r in rows:
        t = by_key[r["task_key"]]
        assert r["config_hash"] == t.point.config_hash
        assert r["p.link.tx_power_w"] == dict(t.point.params)["link.tx_power_w"]
        assert json.loads(r["params_json"]) == dict(t.point.params)
        assert (r["distance_m"], r["seed"], r["trials"]) == (t.distance_m, t.seed, 4)
        assert r["code_version"].startswith(("git:", "lidard "))
        assert 0 <= r["detected"] <= r["trials"]
    # the files are plain Parquet any tool can read
    (part,) = sorted((tmp_path / "a" / "parts").glob("*.parquet"))
    assert pq.read_metadata(part).num_rows == 8
    # summary: one line per configuration and distance, pooled over the two seeds
    assert len(out.summary) == 4 and all(g["tasks"] == 2 and g["trials"] == 8 for g in out.summary)
    assert (tmp_path / "a" / "summary.csv").read_text().count("\n") == 5
    assert out.plot is not None and out.plot.stat().st_size > 10_000
    # the same tasks in this process, without Dask: the same numbers
    ref = run_sweep(sw, tmp_path / "b", in_process=True, plot=False)
    assert ref.ran == 8
    a = {r["task_key"]: [r[k] for k in DETERMINISTIC] for r in rows}
    b = {r["task_key"]: [r[k] for k in DETERMINISTIC] for r in read_results(tmp_path / "b").to_pylist()}
    assert a == b


def test_a_failing_task_is_reported_with_its_parameters_and_the_rest_finish(client, make_sweep, tmp_path):
    # 3 km needs an ADC rate above the digitizer's 1 GHz: those tasks raise inside the worker
    sw = expand_sweep(make_sweep({"scan.max_range_m": [15.0, 3000.0]}, seeds=1))
    out = run_sweep(sw, tmp_path, client=client, plot=False)
    assert out.ran == 4 and len(out.failures) == 2
    for f in out.failures:
        assert f.params["scan.max_range_m"] == 3000.0 and f.params["distance_m"] in (3.0, 12.0)
        assert f.error_type == "ValueError" and "ADC rate" in f.message
    rows = read_results(tmp_path).to_pylist()
    assert len(rows) == 2 and {r["p.scan.max_range_m"] for r in rows} == {15.0}
    failed = json.loads((tmp_path / "failures.json").read_text())
    assert len(failed) == 2 and failed[0]["params"]["scan.max_range_m"] == 3000.0


def test_an_interrupted_sweep_resumes_without_redoing_finished_tasks(make_sweep, tmp_path):
    sw = expand_sweep(make_sweep({"link.tx_power_w": [1e-3, 1e-2]}))
    calls = []

    def interrupted_after_5(task):
        if len(calls) == 5:
            raise KeyboardInterrupt
        calls.append(task.key)
        return run_task(task)

    with pytest.raises(KeyboardInterrupt):
        run_sweep(sw, tmp_path, in_process=True, task_fn=interrupted_after_5, plot=False)
    assert read_results(tmp_path).num_rows == 5        # flushed on the way out

    rerun = []

    def counting(task):
        rerun.append(task.key)
        return run_task(task)

    out = run_sweep(sw, tmp_path, in_process=True, task_fn=counting, plot=False)
    assert (out.skipped, out.ran) == (5, 3) and out.warnings == []
    assert set(rerun) == {t.key for t in sw.tasks} - set(calls)
    assert read_results(tmp_path).num_rows == 8
    again = run_sweep(sw, tmp_path, in_process=True, task_fn=counting, plot=False)
    assert (again.skipped, again.ran) == (8, 0) and len(rerun) == 3


def test_a_resume_with_other_code_says_so(make_sweep, tmp_path, monkeypatch):
    sw = expand_sweep(make_sweep(seeds=1))
    import lidard.offline.results as results
    monkeypatch.setattr(results, "code_version", lambda: "git:old")
    run_sweep(expand_sweep(make_sweep(seeds=1, distances=(3.0,))), tmp_path, in_process=True, plot=False)
    monkeypatch.setattr(results, "code_version", lambda: "git:new")
    out = run_sweep(sw, tmp_path, in_process=True, plot=False)
    assert out.ran == 1 and len(out.warnings) == 1 and "git:old" in out.warnings[0] and "git:new" in out.warnings[0]
    assert {r["code_version"] for r in read_results(tmp_path).to_pylist()} == {"git:old", "git:new"}
