"""Sweep results on disk: Parquet parts (one row per task), resume, and the per-distance summary.

Layout of an output directory::

    OUT/parts/part-<run>-<n>.parquet   rows of finished tasks, written atomically (temp file + rename)
    OUT/summary.csv                    one row per (configuration, distance): pooled over seeds
    OUT/sweep.png                      the plots (lidard.offline.plots)
    OUT/failures.json                  the failed tasks of the last run, with their parameters

Rows carry the task key, the configuration hash, the swept values (``p.<key>`` columns and the same as
JSON in ``params_json``) and the code version, so a part file is self-describing. A restarted sweep
reads the ``task_key`` column of every part and skips those tasks: a part is either complete or
absent (rename is atomic), so an interrupted run loses at most the rows not yet flushed.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import time
import uuid
from collections.abc import Iterable
from pathlib import Path

from . import require_offline_extra
from .spec import SweepTask

PARTS_DIR = "parts"


def code_version() -> str:
    """``git describe`` of the source tree when it is a git checkout, else the package version."""
    root = Path(__file__).resolve().parents[2]
    # only our own checkout (an installed copy may sit inside some unrelated repository)
    if not ((root / ".git").exists() and (root / "pyproject.toml").is_file()):
        return _package_version()
    try:
        out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--tags"],
                             capture_output=True, text=True, timeout=5)
        if out.returncode == 0 and out.stdout.strip():
            return "git:" + out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return _package_version()


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return "lidard " + version("lidard")
    except PackageNotFoundError:
        return "unknown"


def _param_value(v):
    return v if isinstance(v, (bool, int, float, str)) else json.dumps(v)


class ResultStore:
    """Append-only Parquet parts under ``out_dir/parts``; :meth:`done_keys` for resuming."""

    def __init__(self, out_dir: str | Path, *, version: str | None = None, flush_rows: int = 200,
                 flush_s: float = 10.0) -> None:
        require_offline_extra(("pyarrow",))
        self.out_dir = Path(out_dir)
        self.parts = self.out_dir / PARTS_DIR
        self.parts.mkdir(parents=True, exist_ok=True)
        self.version = version or code_version()
        self.flush_rows, self.flush_s = int(flush_rows), float(flush_s)
        # unique per store: two runs into one directory (even in one process, one second) never collide
        self._run = time.strftime("%Y%m%dT%H%M%S") + f"-{uuid.uuid4().hex[:8]}"
        self._n = 0
        self._buf: list[dict] = []
        self._last = time.monotonic()

    def done_keys(self) -> set[str]:
        return {k for k, _ in self.done()}

    def done(self) -> set[tuple[str, str]]:
        """(task key, code version) of every row written so far."""
        import pyarrow.parquet as pq
        out: set[tuple[str, str]] = set()
        for f in sorted(self.parts.glob("*.parquet")):
            t = pq.read_table(f, columns=["task_key", "code_version"])
            out.update(zip(t.column("task_key").to_pylist(), t.column("code_version").to_pylist()))
        return out

    def add(self, task: SweepTask, row: dict) -> None:
        """Buffer one finished task's row; flushes every ``flush_rows`` rows or ``flush_s`` seconds."""
        full = dict(row)
        full["code_version"] = self.version
        full["params_json"] = json.dumps(dict(task.point.params), sort_keys=True)
        for k, v in task.point.params:
            full[f"p.{k}"] = _param_value(v)
        self._buf.append(full)
        if len(self._buf) >= self.flush_rows or time.monotonic() - self._last >= self.flush_s:
            self.flush()

    def flush(self) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq
        self._last = time.monotonic()
        if not self._buf:
            return
        table = pa.Table.from_pylist(self._buf)
        self._n += 1
        final = self.parts / f"part-{self._run}-{self._n:05d}.parquet"
        tmp = final.with_suffix(".parquet.tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, final)          # a part is whole or absent: what resume relies on
        self._buf = []

    def read(self):
        """Every row written so far (all runs), as one pyarrow Table."""
        return read_results(self.out_dir)


def read_results(out_dir: str | Path):
    require_offline_extra(("pyarrow",))
    import pyarrow as pa
    import pyarrow.parquet as pq
    files = sorted((Path(out_dir) / PARTS_DIR).glob("*.parquet"))
    if not files:
        return pa.table({})
    return pa.concat_tables([pq.read_table(f) for f in files], promote_options="default")


def summarize(rows: Iterable[dict], swept_keys: Iterable[str], order: dict[str, int] | None = None) -> list[dict]:
    """Pool the tasks of each (configuration, distance) over seeds: Pd, range bias/RMSE, velocity RMSE.

    ``order`` (configuration hash -> position in the sweep) sorts the configurations as the sweep lists them.
    """
    keys = list(swept_keys)
    groups: dict[tuple, dict] = {}
    for r in rows:
        g = groups.setdefault((r["config_hash"], r["distance_m"], r["reflectivity"], r["velocity_mps"]), {
            "config_hash": r["config_hash"], **{k: r.get(f"p.{k}") for k in keys},
            "distance_m": r["distance_m"], "reflectivity": r["reflectivity"], "velocity_mps": r["velocity_mps"],
            "tasks": 0, "trials": 0, "detected": 0, "false_alarms": 0, "_s": 0.0, "_ss": 0.0, "_vv": 0.0,
            "budget_snr_db": r["budget_snr_db"], "crlb_range_m": r["crlb_range_m"]})
        g["tasks"] += 1
        g["trials"] += r["trials"]
        g["detected"] += r["detected"]
        g["false_alarms"] += r["false_alarms"]
        g["_s"] += r["range_err_sum_m"]
        g["_ss"] += r["range_err_sq_sum_m2"]
        g["_vv"] += r["velocity_err_sq_sum"]
    out = []
    for g in groups.values():
        n = g["detected"]
        s, ss, vv = g.pop("_s"), g.pop("_ss"), g.pop("_vv")
        g["p_detect"] = n / g["trials"] if g["trials"] else math.nan
        g["range_bias_m"] = s / n if n else math.nan
        g["range_rmse_m"] = math.sqrt(ss / n) if n else math.nan
        g["velocity_rmse_mps"] = math.sqrt(vv / n) if n else math.nan
        out.append(g)
    rank = order or {}
    out.sort(key=lambda g: (rank.get(g["config_hash"], len(rank)), g["config_hash"], g["reflectivity"],
                            g["velocity_mps"], g["distance_m"]))
    return out


def write_summary_csv(summary: list[dict], path: str | Path) -> None:
    import csv
    if not summary:
        Path(path).write_text("")
        return
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(summary[0]))
        w.writeheader()
        w.writerows(summary)


def summary_table(summary: list[dict], swept_keys: Iterable[str], *, pd_level: float = 0.9) -> str:
    """One text line per configuration: the farthest distance with Pd >= ``pd_level`` and the RMSEs there."""
    keys = list(swept_keys)
    by_cfg: dict[str, list[dict]] = {}
    for g in summary:
        by_cfg.setdefault(g["config_hash"], []).append(g)
    head = keys + [f"max d (Pd>={pd_level:g})", "Pd there", "range RMSE", "vel RMSE", "tasks"]
    lines = [head]
    for groups in by_cfg.values():
        ok = [g for g in groups if g["p_detect"] >= pd_level]
        far = max(ok, key=lambda g: g["distance_m"]) if ok else None
        lines.append([str(groups[0].get(k)) for k in keys] + (
            [f"{far['distance_m']:.3g} m", f"{far['p_detect']:.2f}", f"{far['range_rmse_m'] * 1e3:.3g} mm",
             f"{far['velocity_rmse_mps'] * 1e3:.3g} mm/s"] if far else ["none", "-", "-", "-"])
            + [str(sum(g["tasks"] for g in groups))])
    widths = [max(len(row[i]) for row in lines) for i in range(len(head))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in lines)
