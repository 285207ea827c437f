"""Reliability table (issue 6): every bench fault, injected at a stated rate or moment into a scan that
goes through the daemon's own job path, with its outcome, what was lost, and for the interlock the
time to safe state on the virtual clock.

Rig: the real instrument (``open_instrument(config/sim.toml, bench="embedded")``: real drivers over a
pty, Modbus TCP and pyusb), a ScanWorker and a Store in a temp dir, scene ``cal_letters``. Each row
runs one 12 x 32-pixel ROI scan (384 bonded pixels, 1 average, 2 m) unless stated, then checks, like
tests/e2e/test_e2e_faults.py:

* data lost = pixels measured (``pixels_scanned``) whose points are not in a parsable file with the
  stored count, plus any temp file left behind. It must be 0 in every row.
* time to safe state (interlock, HV fault): from the virtual moment the interlock opened (set from a
  progress event as "now + delta", delta swept over one safety batch) to the virtual moment laser
  and HV are both read back off (``safe_state.safe_at_s`` in the scan sidecar). The host checks the
  controller's flags between batches of at most ``SAFETY_CHECK_S`` of hardware time; the controller's
  own hardware interlock drops the outputs at once (the host's path is the second line of defence).

    python benchmarks/reliability.py [--sweep 10] [--json] [--tradeoff]

``--tradeoff`` adds the throughput cost of the safety-check interval (CPU-time real-time factor of a
48 x 128-pixel scan per ``SAFETY_CHECK_S`` value).

``run_reliability(...)`` returns the rows and the interlock figures as a dict.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too
from typing import Any
from collections.abc import Callable

import numpy as np

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import SAFETY_CHECK_S, open_instrument
from lidard.instrument import ScanRequest
from lidard.jobs import ScanWorker
from lidard.store import Store

ROI = ScanRequest(pattern="roi", rows=(40, 56), cols=(40, 72), max_range_m=2.0)
N_PIX = 12 * 32
# the interlock sweep needs a scan that is still running one safety batch after the trigger
SWEEP_ROI = ScanRequest(pattern="roi", rows=(40, 72), cols=(0, 128), max_range_m=2.0)
ENV = {"LIDARD__DEVICES__CONTROLLER__TIMEOUT_S": "0.2", "LIDARD__DEVICES__FPSA__TIMEOUT_S": "0.1"}


class Rig:
    def __init__(self, data_dir: str):
        cfg = load_config(CONFIG_DIR / "sim.toml", environ=ENV)
        self.inst = open_instrument(cfg, scene_path=str(CONFIG_DIR / "scenes" / "cal_letters.toml"),
                                    bench="embedded")
        self.bench = self.inst._on_close.__self__
        self.store = Store(data_dir)
        self.worker = ScanWorker(self.inst, self.store, laser=cfg.laser, optics=cfg.optics(),
                                 progress_interval_s=0.0)
        self.worker.start()

    def scan(self, on_progress: Callable[[dict], None] | None = None, req: ScanRequest = ROI):
        rec = self.worker.submit_scan(req)
        if on_progress is not None:
            self.worker.subscribe(rec.id, on_progress)
        return self.worker.wait(rec.id, timeout_s=300)

    def reset(self) -> None:
        self.inst.clear_faults()
        self.inst.controller.clear_faults()

    def close(self) -> None:
        self.worker.stop()
        self.store.close()
        self.inst.close()

    def lost(self, rec) -> int:
        """Measured pixels not safely on disk (0 when nothing was lost) + temp files left."""
        from plyfile import PlyData
        d = self.store.data_dir
        tmp = [p for p in d.rglob("*.tmp")]
        if rec.pixels_scanned == 0:
            return len(tmp)
        if "ply" not in rec.files:
            return rec.pixels_scanned + len(tmp)
        n = len(PlyData.read(str(d / rec.files["ply"]))["vertex"])
        side = json.loads((d / (rec.files["ply"] + ".json")).read_text())
        ok = n == rec.points and side["pixels_scanned"] == rec.pixels_scanned
        return (0 if ok else rec.pixels_scanned) + len(tmp)

    def sidecar(self, rec) -> dict:
        if "ply" not in rec.files:
            return {}
        return json.loads((self.store.data_dir / (rec.files["ply"] + ".json")).read_text())


def _at_pixel(rig: Rig, pixels: int, action: Callable[[], Any]) -> Callable[[dict], None]:
    fired: list = []

    def cb(ev: dict) -> None:
        if ev.get("event") == "progress" and ev.get("pixels_done", 0) >= pixels and not fired:
            fired.append(action())
    return cb


def _outcome(rig: Rig, rec, t_wall: float) -> dict[str, Any]:
    side = rig.sidecar(rec)
    f = side.get("faults", {})
    valid = 0
    if "ply" in rec.files:
        from plyfile import PlyData
        valid = int(np.sum(np.asarray(PlyData.read(str(rig.store.data_dir / rec.files["ply"]))["vertex"]["valid"])))
    return {"state": rec.state, "partial": rec.partial, "pixels": f"{rec.pixels_scanned}/{N_PIX}",
            "valid_points": valid, "error": (rec.error or "")[:110], "batch_retries": f.get("batch_retries", 0),
            "resumes": f.get("resumes", 0), "overrange_pixels": f.get("overrange_pixels", 0),
            "fpsa_retries": rig.inst.fpsa.retry_count, "lost": rig.lost(rec), "wall_s": round(t_wall, 2)}


def run_reliability(sweep: int = 10) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="lidard-reliability-") as tmp:
        rig = Rig(tmp)
        try:
            ref = rig.scan()                       # linearizes first; the reference scan
            rows: list[dict[str, Any]] = []
            inst = rig.inst

            def row(fault: str, moment: str, setup: Callable[[], Any] | None = None,
                    on_progress_factory: Callable[[], Any] | None = None) -> None:
                rig.reset()
                r0 = inst.fpsa.retry_count
                if setup is not None:
                    setup()
                t0 = time.perf_counter()
                rec = rig.scan(on_progress_factory() if on_progress_factory else None)
                out = _outcome(rig, rec, time.perf_counter() - t0)
                out["fpsa_retries"] -= r0
                rows.append({"fault": fault, "rate_or_moment": moment, **out})

            row("none (reference)", "-")
            for rate in (1e-4, 1e-3, 5e-3):
                row("serial_drop", f"rate {rate:g}/byte", lambda r=rate: inst.inject_fault("serial_drop", rate=r))
                row("serial_flip", f"rate {rate:g}/byte", lambda r=rate: inst.inject_fault("serial_flip", rate=r))
            row("serial_disconnect", "before the scan, back after 15 ms (virtual)",
                lambda: inst.inject_fault("serial_disconnect", reconnect_after_s=0.015))
            row("usb_timeout", "digitizer, 2 transfers", lambda: inst.inject_fault("usb_timeout", device="digitizer", n=2))
            row("usb_timeout", "digitizer, until cleared", lambda: inst.inject_fault("usb_timeout", device="digitizer"))
            row("usb_stall", "awg, 1 transfer", lambda: inst.inject_fault("usb_stall", device="awg", n=1))
            row("usb_disconnect", "digitizer, 1 transfer (before arm)",
                lambda: inst.inject_fault("usb_disconnect", device="digitizer", n=1))
            row("usb_disconnect", "digitizer replugged after the first read (2 transfers)", None,
                lambda: _at_pixel(rig, 100, lambda: inst.inject_fault("usb_disconnect", device="digitizer", n=2)))
            row("usb_disconnect", "digitizer unplugged after the first read, stays away", None,
                lambda: _at_pixel(rig, 100, lambda: inst.inject_fault("usb_disconnect", device="digitizer")))
            row("digitizer_overrange", "gain 2000", lambda: inst.inject_fault("digitizer_overrange", gain=2000))
            row("modbus_exception", "code 6 (busy) x2", lambda: inst.inject_fault("modbus_exception", code=6, n=2))
            row("modbus_exception", "code 4 (device failure) x2 (temperature check, bring-up)",
                lambda: inst.inject_fault("modbus_exception", code=4, n=2))
            row("modbus_timeout", "2 responses", lambda: inst.inject_fault("modbus_timeout", n=2))
            row("interlock_open", "first read done (pixel >= 100) + 4 ms", None,
                lambda: _at_pixel(rig, 100, lambda: inst.inject_fault("interlock_open", at_s=rig.bench.clock.now() + 0.004)))
            row("hv_fault", "first read done (pixel >= 100)", None, lambda: _at_pixel(rig, 100, lambda: inst.inject_fault("hv_fault")))
            row("stuck_switch", "col 50 off (scan)", lambda: inst.inject_fault("stuck_switch", line="col", index=50, state="off"))

            # self-test rows
            rig.reset()
            for st in ({"line": "row", "index": 21, "state": "on"}, {"line": "col", "index": 50, "state": "off"}):
                rig.reset()
                inst.inject_fault("stuck_switch", **st)
                rep = rig.worker.submit_selftest().result(timeout=120)
                found = [(s["line"], s["index"], s["state"]) for s in rep["stuck"]]
                rows.append({"fault": "stuck_switch", "rate_or_moment": f"{st['line']} {st['index']} {st['state']} (self-test)",
                             "state": "reported" if found == [(st["line"], st["index"], st["state"])] else f"WRONG {found}",
                             "partial": False, "pixels": "-", "valid_points": 0, "error": "", "batch_retries": 0,
                             "resumes": 0, "overrange_pixels": 0, "fpsa_retries": 0, "lost": 0, "wall_s": 0.0})

            # time to safe state: interlock opening swept across one safety batch
            t_safe = []
            for k in range(sweep):
                rig.reset()
                delta = (k + 0.5) / sweep * SAFETY_CHECK_S
                when: dict[str, float] = {}

                def trip(d=delta):
                    when["at_s"] = rig.bench.clock.now() + d
                    return inst.inject_fault("interlock_open", at_s=when["at_s"])
                rec = rig.scan(_at_pixel(rig, 100, trip), SWEEP_ROI)
                safe = rig.sidecar(rec).get("safe_state", {})
                if safe.get("safe") and "at_s" in when:
                    t_safe.append(safe["safe_at_s"] - when["at_s"])
            rig.reset()
        finally:
            rig.close()
    ts = np.array(t_safe)
    return {"rows": rows, "reference_points": ref.points,
            "interlock": {"safety_check_s": SAFETY_CHECK_S, "trials": int(len(ts)), "of": sweep,
                          "time_to_safe_ms_median": float(np.median(ts) * 1e3) if ts.size else None,
                          "time_to_safe_ms_max": float(ts.max() * 1e3) if ts.size else None,
                          "time_to_safe_ms_min": float(ts.min() * 1e3) if ts.size else None}}


def safety_tradeoff(values_s=(0.01, 0.02, 0.05, 0.2, None), averages: int = 1) -> list[dict[str, Any]]:
    """Cost of the safety check: CPU-time real-time factor (hardware time / process CPU time, bench
    included) of one 48 x 128-pixel scan per ``SAFETY_CHECK_S`` value (None: reads bounded only by
    BATCH_BYTES). CPU time, not wall time, so other load on the machine does not enter."""
    import threading

    import lidard.instrument.scan_loop as li   # where the scan loop reads it
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, scene_path=str(CONFIG_DIR / "scenes" / "cal_letters.toml"), bench="embedded")
    saved = li.SAFETY_CHECK_S
    out = []
    try:
        cal = inst.linearize()
        req = ScanRequest(pattern="roi", rows=(0, 64), cols=(0, 128), averages=averages, max_range_m=2.0)
        for v in values_s:
            li.SAFETY_CHECK_S = 1e9 if v is None else v
            c0 = cpu_time()
            res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
            cpu = cpu_time() - c0
            out.append({"safety_check_s": v, "hardware_s": res.hardware_time_s, "cpu_s": cpu,
                        "rtf_cpu": res.hardware_time_s / cpu, "points": len(res.points)})
    finally:
        li.SAFETY_CHECK_S = saved
        inst.close()
    return out


# the wall-clock figure needs a DSP batch of the full BATCH_BYTES (8 MiB) in the middle of the scan
WALL_ROI = ScanRequest(pattern="roi", rows=(40, 72), cols=(0, 128), max_range_m=2.0, averages=4)


def wall_time_to_safe(trials: int = 8, bench: str = "child", seed: int = 1) -> dict[str, Any]:
    """Time to safe state on WALL time while the DSP works on full batches beside the acquisition.

    Daemon composition (child-process bench: the controller's Modbus server is another process, as
    a real controller is another box). Each trial scans ``WALL_ROI``; when the first full 8 MiB batch
    is handed to the DSP, a helper thread waits a random fraction of one batch's DSP period and
    opens the interlock through the bench's fault injection. Figures, from the moment the injection
    is sent (an upper bound: the loop opens somewhere inside that call) to the safety watch's trip
    record (``SafetyMonitor.last_trip``, monotonic clock): detection, laser/HV off commanded, both read
    back. ``dsp_busy`` says whether DSP batches were in flight (on the DSP workers, beside the
    acquisition) when the interlock opened."""
    import threading

    from lidard.instrument.points import PointBuffer
    from lidard.instrument.scan_loop import BATCH_BYTES

    cfg = load_config(CONFIG_DIR / "sim.toml", environ=ENV)
    inst = open_instrument(cfg, scene_path=str(CONFIG_DIR / "scenes" / "cal_letters.toml"), bench=bench)
    rng = np.random.default_rng(seed)
    # the DSP runs beside the acquisition (worker processes, or threads): the hook is where the
    # acquiring thread hands a full batch over, and the trial's opening lands while it is processed
    original = PointBuffer.flush
    trial: dict[str, Any] = {}
    flush_s: list[float] = []          # time between full hand-overs: one batch's DSP period
    last_full: list[float] = []

    def open_later(delay_s: float, buf: PointBuffer) -> None:
        time.sleep(delay_s)          # wall time on purpose: the opening must land inside the DSP's work
        trial["t_open"] = time.monotonic()
        trial["in_flight"] = buf._pipe.in_flight if buf._pipe is not None else 0
        inst.inject_fault("interlock_open")
        trial["t_injected"] = time.monotonic()

    def timed_flush(self):
        full = self._pending_bytes >= BATCH_BYTES // 4      # a full-size DSP batch, not a scan's short tail
        t0 = time.monotonic()
        try:
            return original(self)
        finally:
            if full:
                if last_full:
                    flush_s.append(t0 - last_full[-1])
                last_full[:] = [t0]
                if trial.get("armed") and "flush" not in trial:
                    trial["flush"] = t0
                    threading.Thread(target=open_later, args=(trial["delay_s"], self), daemon=True).start()

    PointBuffer.flush = timed_flush  # type: ignore[method-assign]
    rows: list[dict[str, Any]] = []
    try:
        inst.run_scan(WALL_ROI, lambda p: None, threading.Event())      # warm-up: the DSP's period
        dsp_s = float(np.median(flush_s)) if flush_s else 0.5
        for _ in range(trials):
            inst.clear_faults()
            inst.controller.clear_faults()
            trial.clear()
            last_full.clear()
            trial.update(armed=True, delay_s=float(rng.uniform(0.1, 0.6)) * dsp_s)
            res = inst.run_scan(WALL_ROI, lambda p: None, threading.Event())
            lt = inst.safety.last_trip or {}
            if "t_open" not in trial or not res.stop_reason or lt.get("wall_safe_s", 0) < trial["t_open"]:
                rows.append({"tripped": False})
                continue
            t0 = trial["t_open"]
            rows.append({"tripped": True, "by": lt["by"], "inject_call_ms": (trial["t_injected"] - t0) * 1e3,
                         "detect_ms": (lt["wall_detected_s"] - t0) * 1e3,
                         "off_commanded_ms": (lt["wall_off_commanded_s"] - t0) * 1e3,
                         "safe_ms": (lt["wall_safe_s"] - t0) * 1e3,
                         "dsp_busy": trial["in_flight"] > 0,
                         "virtual_safe_ms": (lt["safe"]["safe_at_s"] - lt["safe"]["off_commanded_at_s"]) * 1e3})
        inst.clear_faults()
        inst.controller.clear_faults()
    finally:
        PointBuffer.flush = original  # type: ignore[method-assign]
        inst.close()
    ok = [r for r in rows if r["tripped"]]
    safe = np.array([r["safe_ms"] for r in ok])
    return {"bench": bench, "safety_period_s": cfg.daemon.safety_period_s, "dsp_batch_bytes": BATCH_BYTES,
            "dsp_call_s_median": dsp_s, "trials": len(rows), "tripped": len(ok),
            "by_watch": sum(r["by"] == "watch" for r in ok), "dsp_busy": sum(r["dsp_busy"] for r in ok),
            "safe_ms_median": float(np.median(safe)) if ok else None,
            "safe_ms_max": float(safe.max()) if ok else None, "safe_ms_min": float(safe.min()) if ok else None,
            "detect_ms_max": max((r["detect_ms"] for r in ok), default=None),
            "inject_call_ms_max": max((r["inject_call_ms"] for r in ok), default=None), "rows": rows}


def print_wall(w: dict[str, Any]) -> None:
    print(f"\nwall time to safe state ({w['bench']} bench, watch period {w['safety_period_s'] * 1e3:g} ms, "
          f"one {w['dsp_batch_bytes'] >> 20} MiB batch handed to the DSP every {w['dsp_call_s_median']:.2f} s): "
          f"{w['tripped']}/{w['trials']} tripped, {w['by_watch']} by the watch, {w['dsp_busy']} with DSP batches "
          f"in flight at the opening")
    if w["tripped"]:
        print(f"  opening -> laser and HV read back off: median {w['safe_ms_median']:.1f} ms, min "
              f"{w['safe_ms_min']:.1f} ms, max {w['safe_ms_max']:.1f} ms (detection max {w['detect_ms_max']:.1f} "
              f"ms; the injection call itself up to {w['inject_call_ms_max']:.1f} ms of it)")


def print_table(res: dict[str, Any]) -> None:
    hdr = ("fault", "rate or moment", "outcome", "pixels", "valid pts", "retries", "lost")
    print(" | ".join(hdr))
    print(" | ".join("---" for _ in hdr))
    for r in res["rows"]:
        outcome = r["state"] + (" (partial)" if r["partial"] else "")
        if r["error"]:
            outcome += f": {r['error']}"
        retries = (f"fpsa {r['fpsa_retries']}, batch {r['batch_retries']}, resume {r['resumes']}"
                   + (f", overrange px {r['overrange_pixels']}" if r["overrange_pixels"] else ""))
        print(" | ".join(str(x) for x in (r["fault"], r["rate_or_moment"], outcome, r["pixels"],
                                           r["valid_points"], retries, r["lost"])))
    il = res["interlock"]
    print(f"\ninterlock: time to safe state (virtual) over {il['trials']}/{il['of']} openings spread over one "
          f"{il['safety_check_s'] * 1e3:g} ms safety batch: median {il['time_to_safe_ms_median']:.2f} ms, "
          f"min {il['time_to_safe_ms_min']:.2f} ms, max {il['time_to_safe_ms_max']:.2f} ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sweep", type=int, default=10, help="interlock openings across one safety batch")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--tradeoff", action="store_true",
                    help="also measure the throughput cost of the safety-check interval")
    ap.add_argument("--wall", action="store_true",
                    help="only the wall-clock time to safe state with the DSP busy (safety watch)")
    ap.add_argument("--wall-trials", type=int, default=8, help="interlock openings for --wall")
    args = ap.parse_args(argv)
    if args.wall:
        w = wall_time_to_safe(args.wall_trials)
        print(json.dumps(w, indent=1)) if args.json else print_wall(w)
        return 0 if w["tripped"] == w["trials"] else 1
    res = run_reliability(args.sweep)
    if args.tradeoff:
        res["tradeoff"] = safety_tradeoff()
    if args.json:
        print(json.dumps(res, indent=1))
    else:
        print_table(res)
        for t in res.get("tradeoff", []):
            label = "unbounded" if t["safety_check_s"] is None else f"{t['safety_check_s'] * 1e3:g} ms"
            print(f"safety check every {label:>9}: hardware {t['hardware_s']:.3f} s, CPU {t['cpu_s']:.2f} s, "
                  f"real-time factor on CPU time {t['rtf_cpu']:.2f}")
    lost = sum(r["lost"] for r in res["rows"])
    return 0 if lost == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
