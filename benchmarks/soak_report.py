"""Markdown figures of a soak run (benchmarks/soak.py): per-process RSS (the daemon, its child bench)
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


def at_minutes(rows: list[tuple[float, ...]], step_min: float) -> list[tuple[float, ...]]:
    """Median of every column after the time (daemon RSS, bench RSS, and where sampled the daemon's
    anonymous and huge-page MB) in each minute that ends on a multiple of ``step_min``."""
    out = []
    end = rows[-1][0] / 60.0
    marks = [1.0, 2.0] + [float(x) for x in range(int(step_min), int(end) + 1, int(step_min)) if x > 2]
    for m in marks:
        win = [r for r in rows if (m - 1) * 60.0 <= r[0] < m * 60.0]
        if win:
            out.append((m, *(statistics.median(r[k] for r in win) for k in range(1, len(win[0])))))
    return out


def render(res: dict, rows: list[tuple[float, ...]], commit: str, load: str, command: str) -> str:
    d, b = res["rss_mb"], res["bench_rss_mb"]
    minutes = rows[-1][0] / 60.0
    lines = [
        "## Soak: memory of the daemon and of its child bench",
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
        f"| daemon | {d['median_minute_2']:.1f} MB | {d['median_last_minute']:.1f} MB | {d['growth']:+.1f} MB | {d['max']:.1f} MB |",
        f"| child bench | {b['median_minute_2']:.1f} MB | {b['median_last_minute']:.1f} MB | {b['growth']:+.1f} MB | {b['max']:.1f} MB |",
        "",
        "RSS by minute (median of the samples taken after each scan in that minute):",
        "",
    ]
    if len(rows[0]) > 3:        # the daemon's anonymous memory and its share in transparent huge pages
        lines += ["| minute | daemon | bench | daemon anonymous | of which huge pages |", "|---|---|---|---|---|"]
        lines += [f"| {m:g} | {dm:.1f} MB | {bm:.1f} MB | {am:.1f} MB | {hm:.1f} MB |"
                  for m, dm, bm, am, hm in at_minutes(rows, 5.0)]
    else:
        lines += ["| minute | daemon | bench |", "|---|---|---|"]
        lines += [f"| {m:g} | {dm:.1f} MB | {bm:.1f} MB |" for m, dm, bm in at_minutes(rows, 5.0)]
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
        cols = ["t_s", "daemon_mb", "bench_mb"]
        reader = csv.DictReader(f)
        if "daemon_anon_mb" in (reader.fieldnames or []):
            cols += ["daemon_anon_mb", "daemon_anon_huge_mb"]
        rows = [tuple(float(r[k]) for k in cols) for r in reader]
    command = f"nice -n 19 python benchmarks/soak.py --minutes {res['minutes']:g} --json soak.json --rss-csv soak.csv"
    print(render(res, rows, args.commit, args.load, command), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
