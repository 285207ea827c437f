"""Run a sweep end to end: skip finished tasks, run the rest on Dask (or in this process), persist
each row as it arrives, then write the summary, its table and the plots.

Kept apart from the CLI so that tests and notebooks drive the same path with their own client.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .cluster import ProgressCallback, RunReport, TaskFailure, open_client, run_serial, run_tasks
from .results import ResultStore, read_results, summarize, summary_table, write_summary_csv
from .spec import Sweep, SweepTask


@dataclass
class SweepOutcome:
    """What one invocation did: tasks in the sweep, skipped (done before), run now, failed."""

    total: int
    skipped: int
    ran: int
    failures: list[TaskFailure] = field(default_factory=list)
    elapsed_s: float = 0.0
    workers: int = 0
    summary: list[dict] = field(default_factory=list)
    table: str = ""
    plot: Path | None = None
    warnings: list[str] = field(default_factory=list)


def _task_fn() -> Callable[[SweepTask], dict]:
    # imported here: the task module is the composition root that pulls in the simulator
    from .sweep import run_task
    return run_task


def _describe(task: SweepTask) -> dict[str, Any]:
    return task.describe()


def run_sweep(sweep: Sweep, out_dir: str | Path, *, client=None, scheduler: str | None = None,
              workers: int | None = None, processes: bool = True, in_process: bool = False,
              on_progress: ProgressCallback | None = None, plot: bool = True, batch_size: int = 8,
              task_fn: Callable[[SweepTask], dict] | None = None) -> SweepOutcome:
    """Run the tasks of ``sweep`` not yet in ``out_dir``; summarize everything ``out_dir`` holds.

    ``client``: an existing ``distributed.Client`` (tests, notebooks); else ``scheduler`` (an
    address) or a new LocalCluster of ``workers`` processes; ``in_process`` runs without Dask.
    ``batch_size`` sweep tasks share one Dask task (a task is tens of ms; Dask's own cost is ms).
    """
    out = Path(out_dir)
    store = ResultStore(out)
    previous = store.done()
    done = {k for k, _ in previous}
    todo = [t for t in sweep.tasks if t.key not in done]
    wanted = {t.key for t in sweep.tasks}
    older = sorted({v for k, v in previous if k in wanted and v != store.version})
    fn = task_fn or _task_fn()

    def on_result(_i: int, task: SweepTask, row: dict) -> None:
        store.add(task, row)

    report: RunReport
    try:
        if not todo:
            report = RunReport(results=[])
        elif in_process:
            report = run_serial(fn, todo, describe=_describe, on_result=on_result, on_progress=on_progress)
        elif client is not None:
            report = run_tasks(client, fn, todo, describe=_describe, on_result=on_result, on_progress=on_progress,
                               batch_size=batch_size)
        else:
            with open_client(scheduler, n_workers=workers, processes=processes) as c:
                report = run_tasks(c, fn, todo, describe=_describe, on_result=on_result,
                                   on_progress=on_progress, batch_size=batch_size)
    finally:
        store.flush()       # rows of finished tasks survive an interruption
    (out / "failures.json").write_text(json.dumps(
        [{"index": f.index, "params": f.params, "error": f"{f.error_type}: {f.message}"} for f in report.failures],
        indent=1, default=str))
    outcome = SweepOutcome(total=len(sweep.tasks), skipped=len(sweep.tasks) - len(todo), ran=len(todo),
                           failures=report.failures, elapsed_s=report.elapsed_s, workers=report.workers)
    if older and todo:
        # a resumed sweep computed by two versions of the code: say so (the rows keep each version)
        outcome.warnings.append(f"rows already in {out} were computed by {', '.join(older)}; "
                                f"this run is {store.version} (see the code_version column)")
    rows = [r for r in read_results(out).to_pylist() if r["task_key"] in wanted]
    outcome.summary = summarize(rows, sweep.swept_keys, {p.config_hash: i for i, p in enumerate(sweep.points)})
    write_summary_csv(outcome.summary, out / "summary.csv")
    outcome.table = summary_table(outcome.summary, sweep.swept_keys)
    if plot and outcome.summary:
        from .plots import plot_sweep
        outcome.plot = plot_sweep(outcome.summary, sweep.swept_keys, out / "sweep.png",
                                  title=f"{sweep.name}: {len(rows)} tasks")
    return outcome
