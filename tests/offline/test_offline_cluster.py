"""The Dask layer: results in task order, a raising task reported with its parameters while the rest
finish, bounded submission, the serial twin with the same contract, a clear error for a dead address."""

from __future__ import annotations

import pytest

from lidard.offline.cluster import ClusterError, TasksFailed, mapper, open_client, run_serial, run_tasks


def square_or_fail(task: dict) -> int:
    if task["x"] == 3:
        raise ValueError(f"x={task['x']} is cursed")
    return task["x"] ** 2


TASKS = [{"x": i, "name": f"t{i}"} for i in range(8)]


def _check(report, seen, progress):
    assert [r for i, r in enumerate(report.results) if i != 3] == [i * i for i in range(8) if i != 3]
    assert report.results[3] is None
    (f,) = report.failures
    assert f.index == 3 and f.params == {"x": 3, "name": "t3"}
    assert f.error_type == "ValueError" and "cursed" in f.message
    assert "square_or_fail" in f.traceback
    assert sorted(seen) == [i for i in range(8) if i != 3]        # every success handed over once
    assert progress[-1] == (8, 8, 1)
    assert [p[0] for p in progress] == list(range(1, 9))


@pytest.mark.parametrize("batch_size", [1, 3])
def test_run_tasks_on_a_local_cluster_orders_results_and_reports_the_failure(client, batch_size):
    # batch 3: the failing task shares its Dask task with two that succeed
    seen, progress = [], []
    report = run_tasks(client, square_or_fail, TASKS, describe=lambda t: t, max_in_flight=2,
                       batch_size=batch_size, on_result=lambda i, t, r: seen.append(i),
                       on_progress=lambda *a: progress.append(a))
    _check(report, seen, progress)
    assert report.workers == 2 and not report.ok


def test_run_serial_has_the_same_contract():
    seen, progress = [], []
    report = run_serial(square_or_fail, TASKS, describe=lambda t: t,
                        on_result=lambda i, t, r: seen.append(i), on_progress=lambda *a: progress.append(a))
    _check(report, seen, progress)


def test_an_unreachable_scheduler_is_a_clear_error():
    with pytest.raises(ClusterError, match=r"tcp://127\.0\.0\.1:9.*dask scheduler"):
        with open_client("tcp://127.0.0.1:9", connect_timeout_s=1.0):
            pass


def scaled(x: int, k: int) -> int:
    if x == 3:
        raise ValueError("x=3 is cursed")
    return k * x


@pytest.mark.parametrize("on_cluster", [False, True])
def test_mapper_is_map_on_the_cluster_and_names_failed_arguments(client, on_cluster):
    m = mapper(client if on_cluster else None, batch_size=2)
    assert m(scaled, [0, 1, 2, 4], [10, 10, 10, 10]) == list(map(scaled, [0, 1, 2, 4], [10] * 4))
    with pytest.raises(TasksFailed, match=r"1 of 5 tasks failed: task 3 \(3, 7\): ValueError: x=3 is cursed") as ei:
        m(scaled, range(5), [7] * 5)
    assert [f.index for f in ei.value.failures] == [3]
