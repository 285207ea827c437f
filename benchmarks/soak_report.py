"""Markdown figures of a soak run (benchmarks/soak.py): per-process RSS (the daemon; its
child bench, DSP forkserver, DSP workers, resource tracker, each on its own)
at minute marks, their growth from minute 2, and the run's outcome counts.

    nice -n 19 python benchmarks/soak.py --minutes 60 --json soak.json --rss-csv soak.csv
    python benchmarks/soak_report.py soak.json soak.csv --commit COMMIT --load "9-14" > docs/measured/28_soak_memory.md
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
from pathlib import Path


def at_minutes(rows: list[dict[str, float]], cols: list[str], step_min: float) -> list[tuple[float, list[float]]]:
    """Median of each of ``cols`` in each minute that ends on a multiple of ``step_min`` (and minutes 1, 2);
    a column's NaN samples (its process not there) are left out, NaN when all are."""
    out = []
    end = rows[-1]["t_s"] / 60.0
    marks = [1.0, 2.0] + [float(x) for x in range(int(step_min), int(end) + 1, int(step_min)) if x > 2]
    if end - marks[-1] > 0.5:
        marks.append(end)                              # the run's last minute, when no mark ends it
    for m in marks:
        win = [r for r in rows if (m - 1) * 60.0 <= r["t_s"] <= m * 60.0]
        if win:
            vals = []
            for c in cols:
                xs = [r[c] for r in win if r[c] == r[c]]
                vals.append(statistics.median(xs) if xs else float("nan"))
            out.append((m, vals))
    return out


#: (JSON key of the figures, CSV column, name in the tables); the first two are in every run's output,
#: the rest (the DSP pool's processes, the resource tracker, anything else) from the per-role soak on
PROCESSES = [("rss_mb", "daemon_mb", "daemon"), ("bench_rss_mb", "bench_mb", "child bench"),
             ("dsp_forkserver_rss_mb", "dsp_forkserver_mb", "DSP forkserver"),
             ("dsp_workers_rss_mb", "dsp_workers_mb", "DSP workers (together)"),
             ("resource_tracker_rss_mb", "resource_tracker_mb", "resource tracker"),
             ("other_rss_mb", "other_mb", "other children")]


def _mb(x: float) -> str:
    return "-" if x != x else f"{x:.1f} MB"      # NaN: no such process in that minute


def render(res: dict, rows: list[dict[str, float]], commit: str, load: str, command: str) -> str:
    minutes = rows[-1]["t_s"] / 60.0
    lines = [
        "## Soak: memory of the daemon and of each of its child processes",
        "",
        f"`{command}` then `python benchmarks/soak_report.py ...` (this file). Machine: {res['machine']}, "
        f"shared with other sessions' test suites (load average {load}); commit {commit}.",
        "",
        f"Run: {minutes:.1f} minutes, {res['scans']} scans ({', '.join(f'{k} {v}' for k, v in sorted(res['outcomes'].items()))}), "
        f"faults injected {sum(res['faults_injected'].values())}, HTTP 5xx {res['http_5xx']}, points lost "
        f"{res['points_lost']}, clean scans not done {len(res['clean_scans_not_done'])}, temporary files left "
        f"{len(res['temp_files_left'])}.",
        "",
        "| process | RSS minute 2 (median) | RSS last minute (median) | growth from minute 2 | max |",
        "|---|---|---|---|---|",
    ]
    shown = []
    for key, col, name in PROCESSES:
        fig = res.get(key) or {}
        if "growth" in fig:
            lines.append(f"| {name} | {fig['median_minute_2']:.1f} MB | {fig['median_last_minute']:.1f} MB | "
                         f"{fig['growth']:+.1f} MB | {fig['max']:.1f} MB |")
        if col in rows[0] and any(r[col] == r[col] for r in rows):      # sampled and present at least once
            shown.append((col, name))
    extra = [c for c in ("daemon_anon_mb", "daemon_anon_huge_mb") if c in rows[0]]
    cols = [c for c, _ in shown] + extra
    names = [n for _, n in shown] + ["daemon anonymous", "of which huge pages"][:len(extra)]
    lines += ["", "RSS by minute (median of the samples taken after each scan in that minute; - : no such process):", "",
              "| minute | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    lines += [f"| {m:.3g} | " + " | ".join(_mb(v) for v in vals) + " |" for m, vals in at_minutes(rows, cols, 5.0)]
    if "dsp_workers_n" in rows[0]:
        ns = sorted({int(r["dsp_workers_n"]) for r in rows})
        lines += ["", f"DSP workers alive at a sample: {', '.join(map(str, ns))}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("json", help="the soak's --json output")
    ap.add_argument("csv", help="the soak's --rss-csv output")
    ap.add_argument("--commit", default="?", help="the commit the soak ran")
    ap.add_argument("--load", default="?", help="the load average seen during the run")
    args = ap.parse_args(argv)
    res = json.loads(Path(args.json).read_text())
    with open(args.csv) as f:
        rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]
    command = f"nice -n 19 python benchmarks/soak.py --minutes {res['minutes']:g} --json soak.json --rss-csv soak.csv"
    print(render(res, rows, args.commit, args.load, command), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
