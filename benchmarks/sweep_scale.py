"""Scale-out of sweep tasks on Dask: per-task cost, scheduling overhead, throughput with 1 and 2 worker
processes against the in-process path, and the MODEL for 10 and 100 workers (issue 17).

    python -m benchmarks.sweep_scale [--tasks 80] [--noop 400] [--json FILE]

Measured, side by side in one run, every variant ``--repeats`` times interleaved, best run of each
(the machine is shared: a burst of load from elsewhere hits the variants alike; read ratios):

* in-process: the sweep's tasks one after the other in this process (``run_serial``), no Dask;
* LocalCluster with 1 and with 2 worker processes (one thread each; both clusters stay up for the
  whole run): the same tasks through ``run_tasks``; start-up is timed apart, not in the throughput;
* the same with 8 sweep tasks per Dask task (``--batch`` of lidarctl sweep);
* scheduling overhead: NO-OP tasks that take the same pickled task object and return a row-sized dict,
  through 1 worker: wall time / task is what Dask adds per task (serialize, schedule, run, return);
* data volume: pickled bytes of a task (what travels to a worker) and of its result row (back).

Model (not measured) for N workers of the same speed: a worker finishes a task every c + o_w seconds
(c: compute, o_w: the worker's share of the overhead); the scheduler dispatches at most 1 / o_s tasks
per second (o_s: its per-task cost, bounded here by the no-op rate, which includes the client), so
throughput(N) = min(N / (c + o_w), B / o_s) with B sweep tasks per Dask task, and the network carries
throughput x (task + row) bytes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import pickle
import time
from pathlib import Path

from lidard.offline.cluster import open_client, run_serial, run_tasks
from lidard.offline.spec import load_sweep
from lidard.offline.sweep import run_task

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "config" / "sweeps" / "lasers_powers.toml"
BATCH = 8           # lidarctl sweep --batch default


def noop_task(task) -> dict:
    """Touches the task (so it is shipped and unpickled) and returns a row-sized dict."""
    return {"task_key": task.key, "detected": 0, "x": [0.0] * 30}


def _tasks(n: int):
    tasks = load_sweep(SPEC).tasks
    step = max(1, len(tasks) // n)
    return tasks[::step][:n]           # spread over lasers, powers, distances, seeds


def _best(reps: list) -> tuple:
    """(best run, its wall time, the median wall time) of repeated runs."""
    w = sorted(reps, key=lambda r: r.elapsed_s)
    return w[0], w[0].elapsed_s, w[len(w) // 2].elapsed_s


def measure(n_tasks: int, n_noop: int, repeats: int = 3) -> dict:
    """Every variant ``repeats`` times, interleaved, so a burst of load on the shared machine hits all
    of them alike; the best run of each is the figure (the median is kept too)."""
    tasks = _tasks(n_tasks)
    noop_tasks = (tasks * (n_noop // len(tasks) + 1))[:n_noop]
    run_serial(run_task, tasks[:2])                           # warm imports and caches
    load0 = os.getloadavg()[0]
    modes = ("in_process", "workers_1", "workers_2", f"workers_1_batch{BATCH}", f"workers_2_batch{BATCH}")
    runs: dict[str, list] = {k: [] for k in modes + ("noop_1", "noop_2")}
    startup = {}
    with contextlib.ExitStack() as stack:
        clients = {}
        for w in (1, 2):
            t0 = time.perf_counter()
            clients[w] = stack.enter_context(open_client(n_workers=w, processes=True))
            startup[w] = time.perf_counter() - t0
            run_tasks(clients[w], run_task, tasks[: 2 * w])  # warm the workers' imports and caches
        for _ in range(repeats):
            runs["in_process"].append(run_serial(run_task, tasks))
            for w in (1, 2):
                runs[f"workers_{w}"].append(run_tasks(clients[w], run_task, tasks))
                runs[f"workers_{w}_batch{BATCH}"].append(run_tasks(clients[w], run_task, tasks, batch_size=BATCH))
                runs[f"noop_{w}"].append(run_tasks(clients[w], noop_task, noop_tasks))
    for k, reps in runs.items():
        for r in reps:
            if r.failures:
                raise RuntimeError(f"{k}: {r.failures[0].summary()}")
    rows = _best(runs["in_process"])[0].results
    pixels = len(tasks) * tasks[0].trials
    out = {"tasks": len(tasks), "trials_per_task": tasks[0].trials, "repeats": repeats,
           "load_avg_start": load0, "task_compute_s": sum(r["elapsed_s"] for r in rows) / len(rows),
           "task_bytes": len(pickle.dumps(tasks[0])), "row_bytes": len(pickle.dumps(rows[0])),
           "samples_per_task": rows[0]["samples"]}
    for k in modes:
        run, best, med = _best(runs[k])
        out[k] = {"wall_s": best, "median_wall_s": med, "tasks_per_s": len(tasks) / best,
                  "pixels_per_s": pixels / best}
        if k != "in_process":
            out[k]["startup_s"] = startup[int(k.split("_")[1])]
            # compute time inside the tasks on the workers (same run): above in-process = CPU starvation
            out[k]["task_compute_s"] = sum(r["elapsed_s"] for r in run.results) / len(run.results)
    for w in (1, 2):
        _, best, med = _best(runs[f"noop_{w}"])
        out[f"noop_workers_{w}"] = {"wall_s": best, "median_wall_s": med, "tasks_per_s": n_noop / best,
                                    "overhead_per_task_ms": 1e3 * best / n_noop}
    out["load_avg_end"] = os.getloadavg()[0]
    return out


def model(m: dict) -> dict:
    """Throughput of N workers from the measured per-task figures (see the module docstring).

    o_s, the scheduler's (and client's) cost per Dask task, is bounded by the no-op rate with 2 workers;
    o_w, a worker's extra time per sweep task, is one worker's wall time per task minus the compute time
    measured inside the tasks of the same run (so CPU stolen by other processes is not counted as
    Dask's). c is the in-process compute time. With B sweep tasks per Dask task the scheduler limit
    becomes B / o_s sweep tasks per second.
    """
    c = m["task_compute_s"]
    o_s = 1.0 / m["noop_workers_2"]["tasks_per_s"]
    out = {"c_s": c, "o_s_s": o_s}
    for b, key in ((1, "workers_1"), (BATCH, f"workers_1_batch{BATCH}")):
        o_w = max(0.0, 1.0 / m[key]["tasks_per_s"] - m[key]["task_compute_s"])
        for n in (10, 100):
            worker_rate, sched_rate = n / (c + o_w), b / o_s
            rate = min(worker_rate, sched_rate)
            out[f"batch{b}_N{n}"] = {"o_w_s": o_w, "tasks_per_s": rate,
                                     "bound": "workers" if worker_rate < sched_rate else "scheduler",
                                     "sweep_3600_s": 3600 / rate,
                                     "network_kb_per_s": rate * (m["task_bytes"] + m["row_bytes"]) / 1e3}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", type=int, default=80)
    ap.add_argument("--noop", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    m = measure(a.tasks, a.noop, a.repeats)
    m["model"] = model(m)
    ip, w1, w2 = m["in_process"], m["workers_1"], m["workers_2"]
    print(f"{m['tasks']} tasks x {m['trials_per_task']} pixels, best of {m['repeats']}; load average {m['load_avg_start']:.1f} -> "
          f"{m['load_avg_end']:.1f}")
    print(f"in-process : {ip['tasks_per_s']:.1f} tasks/s  {ip['pixels_per_s']:.0f} pixels/s  "
          f"(compute {m['task_compute_s'] * 1e3:.1f} ms/task)")
    for k, r in (("1 worker  ", w1), ("2 workers ", w2), (f"1 worker,  batch {BATCH}", m[f"workers_1_batch{BATCH}"]),
                 (f"2 workers, batch {BATCH}", m[f"workers_2_batch{BATCH}"])):
        print(f"{k} : {r['tasks_per_s']:.1f} tasks/s  {r['pixels_per_s']:.0f} pixels/s  "
              f"x{r['tasks_per_s'] / ip['tasks_per_s']:.2f} of in-process  (start-up {r['startup_s']:.1f} s, "
              f"compute in the workers {r['task_compute_s'] * 1e3:.1f} ms/task)")
    for w in (1, 2):
        r = m[f"noop_workers_{w}"]
        print(f"no-op, {w} worker(s): {r['tasks_per_s']:.0f} tasks/s = {r['overhead_per_task_ms']:.2f} ms/task")
    print(f"data: task {m['task_bytes']} B pickled, row {m['row_bytes']} B, {m['samples_per_task']} samples "
          "synthesized per task")
    mo = m["model"]
    for b in (1, BATCH):
        for n in (10, 100):
            r = mo[f"batch{b}_N{n}"]
            print(f"MODEL batch {b}, N={n}: {r['tasks_per_s']:.0f} tasks/s ({r['bound']}-bound), 3600-task sweep "
                  f"{r['sweep_3600_s']:.0f} s, network {r['network_kb_per_s']:.0f} kB/s")
    if a.json:
        Path(a.json).write_text(json.dumps(m, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
