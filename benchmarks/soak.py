"""Soak of a REAL daemon (issue 11, item 5): faults from the catalogue injected at random before small
scans, cleared (and latched controller faults acknowledged) after each, for a stated wall time.

Rig: ``python -m lidard --config config/sim.toml`` in its own process (child-process simulated bench,
temp data dir, an ephemeral port), driven over HTTP like a lab client: it holds the control lock,
posts 4 x 8-pixel ROI scans of the CAL scene, and between scans injects one random fault (or none)
from a mix that covers every catalogue kind that can be cleared (stuck switches are left out: they
only change self-test answers, not scans).

Reported (and checked at the end):

* scans by outcome, and how many started with no active fault and still did not end ``done`` or were
  refused (target 0: after its acknowledgement the instrument must be usable again);
* faults injected by kind; acknowledgements (``POST /controller/acknowledge``) and their answers;
* files checked against the store: every ``done``/failed scan's PLY, fetched over HTTP
  (``GET /scans/{id}/points``), parses and holds exactly the stored point count (``counts.points``);
  measured points without a file count as lost (data lost = 0);
* HTTP 5xx answers (target 0), temporary files left under the data dir (target 0);
* memory per process (VmRSS of the daemon and, separately, of each of its descendants by role,
  sampled once per scan: the child bench, the DSP pool's forkserver, its workers together, the
  resource tracker, anything else; roles told apart by command line, see :func:`role_of`): the median of the last minute against the median of minute 2 (``growth``; target: each
  within 10 MB, however long the run), and the median of the last 5 minutes against minutes 2-6
  (``drift``). ``--rss-csv FILE`` writes every sample (seconds, daemon MB, bench MB, and where the daemon's memory
  is: anonymous MB, of which in transparent huge pages, threads; then the other roles' MB).

    nice -n 19 python benchmarks/soak.py --minutes 60 [--seed 1] [--json out.json] [--rss-csv rss.csv]

The figures of a run go to docs/reliability.md with the machine and the command;
``benchmarks/soak_report.py`` renders the JSON and the CSV as markdown (docs/measured/28_soak_memory.md).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import platform
import random
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import httpx
from plyfile import PlyData

try:
    from benchmarks import soak_smaps
except ImportError:            # run as a script: benchmarks/ itself is on sys.path
    import soak_smaps          # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]

# kind -> parameters; scans are injected into before they start, and cleared after they end
FAULT_MIX: list[tuple[str, dict[str, Any]]] = [
    ("serial_drop", {"rate": 1e-3}),
    ("serial_flip", {"rate": 1e-3}),
    ("serial_disconnect", {"reconnect_after_s": 0.05}),
    ("usb_timeout", {"device": "digitizer", "n": 2}),
    ("usb_timeout", {"device": "awg", "n": 1}),
    ("usb_stall", {"device": "awg", "n": 1}),
    ("usb_disconnect", {"device": "digitizer", "n": 1}),
    ("digitizer_overrange", {}),
    ("modbus_exception", {"code": 6, "n": 2}),
    ("modbus_exception", {"code": 4, "n": 1}),
    ("modbus_timeout", {"n": 1}),
    ("interlock_open", {"after_segments": 3}),
    ("hv_fault", {}),
]
SCAN_BODY = {"pattern": "roi", "rows": [40, 44], "cols": [48, 56], "max_range_m": 2.0, "averages": 1}
SCAN_TIMEOUT_S = 120.0


def start_daemon(data_dir: Path) -> tuple[subprocess.Popen, str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1",
           # short device timeouts: an injected timeout costs a fraction of a second, not seconds
           "LIDARD__DEVICES__CONTROLLER__TIMEOUT_S": "0.2", "LIDARD__DEVICES__FPSA__TIMEOUT_S": "0.2",
           # the soak measures scans under faults; the bench's factory calibration before the first
           # scan (with faults injected from the start) is not what it measures
           "LIDARD__SIM__FACTORY_CALIBRATION": "false"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "lidard", "--config", str(REPO / "config" / "sim.toml"), "--port", "0",
         "--data-dir", str(data_dir), "--log-level", "warning"],
        cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        start_new_session=True)
    deadline = time.monotonic() + 90.0
    while time.monotonic() < deadline:
        line = proc.stderr.readline().decode(errors="replace")
        if not line and proc.poll() is not None:
            break
        m = re.search(r"serving on (http://[\d.]+:\d+)", line)
        if m:
            url = m.group(1)
            while time.monotonic() < deadline:
                try:
                    if httpx.get(url + "/health", timeout=2.0).status_code == 200:
                        # keep draining stderr so the daemon never blocks on a full pipe
                        _drain(proc)
                        return proc, url
                except httpx.TransportError:
                    time.sleep(0.1)
    stop_daemon(proc)
    raise RuntimeError("lidard did not come up")


def _drain(proc: subprocess.Popen) -> None:
    import threading

    def run():
        for _ in iter(lambda: proc.stderr.readline(), b""):
            pass
    threading.Thread(target=run, daemon=True).start()


def stop_daemon(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=30)


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def heap_detail(pid: int) -> tuple[float, float, int]:
    """Where a process's memory is: anonymous MB, of which in transparent huge pages (MB), threads."""
    anon = huge = float("nan")
    threads = 0
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Anonymous:"):
                anon = int(line.split()[1]) / 1024.0
            elif line.startswith("AnonHugePages:"):
                huge = int(line.split()[1]) / 1024.0
        threads = len(list(Path(f"/proc/{pid}/task").iterdir()))
    except OSError:
        pass
    return anon, huge, threads


def children(pid: int) -> list[int]:
    """The direct children of ``pid``."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


#: the roles of the daemon's descendants, as the soak reports them (each its own RSS column)
ROLES = ("bench", "dsp_forkserver", "dsp_workers", "resource_tracker", "other")


def role_of(cmd: str, parent_role: str | None) -> str:
    """What a descendant of the daemon is, from its command line (and its parent's role): the simulated
    bench (``-m sim_devices.bench.bench``), the DSP pool's forkserver (a child of the daemon running
    ``multiprocessing.forkserver``), the pool's workers (the forkserver's children, same command line),
    multiprocessing's resource tracker, or something else."""
    if "sim_devices.bench.bench" in cmd:
        return "bench"
    if "multiprocessing.forkserver" in cmd:
        return "dsp_workers" if parent_role == "dsp_forkserver" else "dsp_forkserver"
    if "multiprocessing.resource_tracker" in cmd:
        return "resource_tracker"
    return "other"


def descendants_by_role(pid: int) -> dict[str, list[int]]:
    """Every descendant of ``pid`` (children, their children, ...) by :func:`role_of`."""
    out: dict[str, list[int]] = {r: [] for r in ROLES}
    todo: list[tuple[int, str | None]] = [(k, None) for k in children(pid)]
    while todo:
        k, parent_role = todo.pop()
        role = role_of(cmdline(k), parent_role)
        out[role].append(k)
        todo += [(g, role) for g in children(k)]
    return out


def rss_by_role(pid: int) -> dict[str, tuple[float, int]]:
    """role -> (VmRSS of its processes together in MB, NaN when there is none; how many processes)."""
    out: dict[str, tuple[float, int]] = {}
    for role, pids in descendants_by_role(pid).items():
        mbs = [m for m in (rss_mb(k) for k in pids) if not math.isnan(m)]
        out[role] = (sum(mbs) if mbs else float("nan"), len(mbs))
    return out


class Client:
    """HTTP with the control lease (every request carrying it renews it); counts answers by class."""

    def __init__(self, url: str):
        self.http = httpx.Client(base_url=url, timeout=30.0)
        self.status = Counter()
        r = self.http.post("/control", json={"client": "soak@bench"})
        r.raise_for_status()
        self.http.headers["X-Lidard-Lease"] = r.json()["lease"]

    def call(self, method: str, path: str, **kw) -> httpx.Response:
        r = self.http.request(method, path, **kw)
        self.status[r.status_code] += 1
        return r


def wait_scan(c: Client, sid: str) -> dict[str, Any]:
    deadline = time.monotonic() + SCAN_TIMEOUT_S
    while time.monotonic() < deadline:
        rec = c.call("GET", f"/scans/{sid}").json()
        if rec["state"] in ("done", "failed", "cancelled", "interrupted"):
            return rec
        time.sleep(0.05)
    c.call("DELETE", f"/scans/{sid}")
    return {"state": "timeout", "id": sid}


def check_files(c: Client, rec: dict[str, Any]) -> tuple[int, int]:
    """(files checked, points lost) for one ended scan: its PLY, fetched like a lab client would
    (GET /scans/{id}/points), must parse and hold exactly the point count the store reports."""
    points = int(rec["counts"]["points"])
    if "ply" not in (rec.get("formats") or []):
        return 0, points                  # measured points with no file are lost
    r = c.call("GET", f"/scans/{rec['id']}/points", params={"format": "ply"})
    if r.status_code != 200:
        return 1, points
    n = len(PlyData.read(io.BytesIO(r.content))["vertex"])
    return 1, abs(n - points)


def soak(minutes: float, seed: int = 1, p_fault: float = 0.6, smaps_dir: Path | None = None,
         smaps_every_s: float = 20.0) -> dict[str, Any]:
    rng = random.Random(seed)
    tmp = tempfile.TemporaryDirectory(prefix="lidard-soak-")
    data_dir = Path(tmp.name)
    proc, url = start_daemon(data_dir)
    c = Client(url)
    outcomes: Counter = Counter()
    injected: Counter = Counter()
    acks: Counter = Counter()
    clean_not_done: list[dict[str, Any]] = []
    rss: list[tuple[float, float]] = []
    kids: dict[str, list[tuple[float, float]]] = {r: [] for r in ROLES}   # role -> (s, MB) samples
    n_workers: list[int] = []
    detail: list[tuple[float, float, int]] = []         # the daemon's anonymous / huge-page MB, threads
    refused_injections: list[dict[str, Any]] = []
    ack_refusals: list[str] = []
    lost = scans = files_checked = 0
    by_fault: dict[str, Counter] = defaultdict(Counter)   # injected kind ("none") -> outcomes
    t0 = time.monotonic()
    smaps_next, smaps_k = 0.0, 0        # the next memory-map sample (benchmarks/soak_smaps.py)
    try:
        while time.monotonic() - t0 < minutes * 60.0:
            fault = rng.choice(FAULT_MIX) if rng.random() < p_fault else None
            if fault is not None:
                kind, params = fault
                r = c.call("POST", "/sim/faults", json={"kind": kind, **params})
                if r.status_code == 201:
                    injected[kind] += 1
                else:                         # the fault is not active: the scan still counts as faulted
                    refused_injections.append({"kind": kind, "status": r.status_code, "detail": r.text[:200]})
            r = c.call("POST", "/scans", json=SCAN_BODY)
            if r.status_code == 409:          # a latched fault: acknowledge and go on
                outcomes["refused_latched"] += 1
                by_fault[fault[0] if fault else "none"]["refused_latched"] += 1
                if fault is None:             # nothing was injected: the last acknowledgement failed
                    clean_not_done.append({"state": "refused", "error": r.text[:300]})
            elif r.status_code == 201:
                rec = wait_scan(c, r.json()["id"])
                scans += 1
                outcomes[rec["state"]] += 1
                by_fault[fault[0] if fault else "none"][rec["state"]] += 1
                if rec["state"] in ("done", "failed"):
                    checked, n_lost = check_files(c, rec)
                    files_checked += checked
                    lost += n_lost
                if fault is None and rec["state"] != "done":
                    clean_not_done.append({"id": rec.get("id"), "state": rec["state"],
                                           "error": rec.get("error")})
            else:
                outcomes[f"http_{r.status_code}"] += 1
            c.call("DELETE", "/sim/faults")
            a = c.call("POST", "/controller/acknowledge")
            acks[a.status_code] += 1
            if a.status_code != 200:
                ack_refusals.append(a.text[:300])
            t_now = time.monotonic() - t0
            rss.append((t_now, rss_mb(proc.pid)))
            for role, (mb, n) in rss_by_role(proc.pid).items():
                kids[role].append((t_now, mb))
                if role == "dsp_workers":
                    n_workers.append(n)
            detail.append(heap_detail(proc.pid))
            if smaps_dir is not None and t_now >= smaps_next:
                soak_smaps.write_sample(smaps_dir, smaps_k, t_now, {
                    "daemon": [proc.pid], "bench": descendants_by_role(proc.pid)["bench"]})
                smaps_next, smaps_k = t_now + smaps_every_s, smaps_k + 1
    finally:
        tmp_left = [str(p) for p in data_dir.rglob("*.tmp")]
        stop_daemon(proc)
        tmp.cleanup()
    return {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
        "minutes": minutes, "seed": seed, "scans": scans, "outcomes": dict(outcomes),
        "outcomes_by_fault": {k: dict(v) for k, v in sorted(by_fault.items())},
        "faults_injected": dict(injected), "acknowledgements": {str(k): v for k, v in acks.items()},
        "injections_refused": refused_injections, "acknowledgement_refusals": ack_refusals[:20],
        "clean_scans_not_done": clean_not_done, "files_checked": files_checked, "points_lost": lost,
        "http": {str(k): v for k, v in c.status.items()}, "http_5xx": sum(v for k, v in c.status.items() if k >= 500),
        "temp_files_left": tmp_left, "rss_mb": memory_figures(rss),
        **{f"{role}_rss_mb": memory_figures(kids[role]) for role in ROLES},
        "rss_samples": [(round(t, 1), round(d, 2), *(round(kids[r][i][1], 2) for r in ROLES[:1]),
                         round(a, 2), round(h, 2), n,
                         *(round(kids[r][i][1], 2) for r in ROLES[1:]), n_workers[i])
                        for i, ((t, d), (a, h, n)) in enumerate(zip(rss, detail))],
    }


def memory_figures(rss: list[tuple[float, float]]) -> dict[str, Any]:
    """Medians of the daemon's RSS: minutes 2-6 against the last 5 minutes (the issue's target)."""
    rss = [(t, m) for t, m in rss if not math.isnan(m)]   # NaN: the process was not there to sample
    if not rss:
        return {}
    end = rss[-1][0]
    minute_2 = [m for t, m in rss if 60.0 <= t < 120.0]
    last_minute = [m for t, m in rss if t >= end - 60.0]
    early = [m for t, m in rss if 120.0 <= t < 360.0]
    late = [m for t, m in rss if t >= end - 300.0]
    out = {"first": rss[0][1], "last": rss[-1][1], "max": max(m for _, m in rss),
           "samples": len(rss)}
    if early and late:
        out.update(median_min_2_6=statistics.median(early), median_last_5=statistics.median(late),
                   drift=statistics.median(late) - statistics.median(early))
    if minute_2 and last_minute and end >= 180.0:
        out.update(median_minute_2=statistics.median(minute_2), median_last_minute=statistics.median(last_minute),
                   growth=statistics.median(last_minute) - statistics.median(minute_2))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=15.0, help="wall time to run (minutes)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the fault choice")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--rss-csv", default=None, help="write every RSS sample here: seconds, daemon MB, bench MB, daemon anonymous MB, "
                         "of which huge pages, daemon threads, then the MB of the DSP forkserver, of the DSP workers "
                         "together, of the resource tracker, of any other child, and the number of DSP workers")
    ap.add_argument("--smaps-dir", type=Path, default=None,
                    help="also write the memory maps and threads of the daemon and its bench here, one JSON file "
                         "a sample (read them with benchmarks/soak_smaps.py)")
    ap.add_argument("--smaps-every", type=float, default=20.0, help="seconds between two --smaps-dir samples")
    args = ap.parse_args(argv)
    if args.smaps_every <= 0:
        ap.error(f"--smaps-every must be > 0 seconds, got {args.smaps_every}")
    res = soak(args.minutes, args.seed, smaps_dir=args.smaps_dir, smaps_every_s=args.smaps_every)
    samples = res.pop("rss_samples")
    if args.rss_csv:
        Path(args.rss_csv).write_text("t_s,daemon_mb,bench_mb,daemon_anon_mb,daemon_anon_huge_mb,daemon_threads,"
                                      + ",".join(f"{r}_mb" for r in ROLES[1:]) + ",dsp_workers_n\n"
                                      + "".join(",".join(map(str, row)) + "\n" for row in samples))
    print(json.dumps(res, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2))
    ok = (not res["clean_scans_not_done"] and res["points_lost"] == 0 and res["http_5xx"] == 0
          and not res["temp_files_left"])
    for mem in (res["rss_mb"], *(res[f"{role}_rss_mb"] for role in ROLES)):
        if "growth" in mem:
            ok = ok and mem["growth"] <= 10.0
    print("soak targets", "MET" if ok else "NOT MET")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
