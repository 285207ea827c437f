"""The memory maps of a soak's processes, sampled beside it, and the changes between samples.

``python benchmarks/soak.py --smaps-dir DIR ...`` writes, every ``--smaps-every`` seconds, one JSON file
per sample (``DIR/00012.json``): for the daemon and its child bench, every mapping of
``/proc/PID/smaps`` (address range, permissions, name, size, RSS, anonymous kB) and the process's
threads (id and name). A step of a process's RSS is then a diff of two samples: which mapping grew or
appeared (a glibc arena heap: an anonymous mapping starting on a 64 MiB boundary; a thread stack: 8 MiB),
and whether threads came with it.

``python benchmarks/soak_smaps.py DIR [--role bench] [--min-kb 512]`` prints, sample after sample, the
process's RSS and thread count, and the mappings whose RSS changed by at least ``--min-kb``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

_FIELDS = {"Size:": "size_kb", "Rss:": "rss_kb", "Anonymous:": "anon_kb"}


def mappings(pid: int) -> list[dict[str, Any]]:
    """Every mapping of ``pid`` with its size, RSS and anonymous kB (empty if the process is gone)."""
    out: list[dict[str, Any]] = []
    try:
        text = Path(f"/proc/{pid}/smaps").read_text()
    except OSError:
        return out
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] in _FIELDS and out:
            out[-1][_FIELDS[parts[0]]] = int(parts[1])
        elif "-" in parts[0] and not parts[0].endswith(":"):
            out.append({"range": parts[0], "perm": parts[1], "name": " ".join(parts[5:])})
    return out


def threads(pid: int) -> list[list[Any]]:
    """[thread id, name] of every thread of ``pid``."""
    out: list[list[Any]] = []
    try:
        tasks = sorted(Path(f"/proc/{pid}/task").iterdir(), key=lambda p: int(p.name))
    except OSError:
        return out
    for task in tasks:
        try:
            out.append([int(task.name), (task / "comm").read_text().strip()])
        except OSError:
            continue
    return out


def write_sample(directory: Path, index: int, t_s: float, pids: dict[str, list[int]]) -> None:
    """One sample of the processes ``pids`` (role -> process ids) at ``t_s`` seconds into the soak."""
    directory.mkdir(parents=True, exist_ok=True)
    procs = {role: [{"pid": pid, "threads": threads(pid), "maps": mappings(pid)} for pid in ids]
             for role, ids in pids.items()}
    (directory / f"{index:05d}.json").write_text(json.dumps({"t_s": round(t_s, 1), "processes": procs}))


def _changes(before: list[dict[str, Any]], after: list[dict[str, Any]], min_kb: int) -> list[str]:
    # a mapping is known by its start: a heap that grows keeps its start and moves its end
    old = {m["range"].split("-")[0]: m for m in before}
    new = {m["range"].split("-")[0]: m for m in after}
    lines = []
    for start, m in new.items():
        was = old.get(start, {}).get("rss_kb", 0)
        if abs(m.get("rss_kb", 0) - was) >= min_kb:
            tag = ("grew" if m.get("rss_kb", 0) > was else "shrank") if start in old else "new"
            lines.append(f"  {tag:6s} {m['range']} {m['perm']} {m['name'] or '[anon]'} size {m.get('size_kb', 0)} kB, "
                         f"rss {was} -> {m.get('rss_kb', 0)} kB")
    for start, m in old.items():
        if start not in new and m.get("rss_kb", 0) >= min_kb:
            lines.append(f"  gone   {m['range']} {m['perm']} {m['name'] or '[anon]'} rss {m.get('rss_kb', 0)} kB")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("directory", help="the --smaps-dir of a soak")
    ap.add_argument("--role", default="bench", help="daemon or bench (default bench)")
    ap.add_argument("--min-kb", type=int, default=512, help="report mappings whose RSS moved by this much")
    args = ap.parse_args(argv)
    files = sorted(Path(args.directory).glob("*.json"))
    if not files:
        raise SystemExit(f"soak_smaps: no samples in {args.directory}")
    prev: dict[str, Any] | None = None
    for f in files:
        sample = json.loads(f.read_text())
        procs = sample["processes"].get(args.role) or []
        if not procs:
            continue
        p = procs[0]
        rss = sum(m.get("rss_kb", 0) for m in p["maps"])
        print(f"{sample['t_s']:8.1f} s  pid {p['pid']}  RSS {rss / 1024:7.1f} MB  threads {len(p['threads'])}")
        if prev is not None and prev["pid"] == p["pid"]:
            for line in _changes(prev["maps"], p["maps"], args.min_kb):
                print(line)
            born = sorted(set(map(tuple, p["threads"])) - set(map(tuple, prev["threads"])))
            gone = sorted(set(map(tuple, prev["threads"])) - set(map(tuple, p["threads"])))
            if born or gone:
                print(f"  threads new {born} gone {gone}")
        prev = p
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
