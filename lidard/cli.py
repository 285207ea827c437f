"""Command-line entry points: ``lidard`` (the daemon) and ``lidarctl`` (the client and offline tools).

``lidarctl optics`` prints the FPSA figures of Table 4-1 (eqs. 4-1..4-16) for a profile and lens,
``lidarctl budget`` the link budget of §2.4.1 (eqs. 2-9..2-21, Fig. 2-8) at one distance; ``scan``,
``status``, ``devices``, ``scans`` and ``linearize`` talk to a running daemon over HTTP (httpx), or,
with ``--sim``, start an embedded simulated bench and run the daemon's own job code (lidard.jobs) in
process.

Every failure (bad option, unreachable daemon, bad configuration, device fault) is printed as ONE
line on stderr and a non-zero exit status; set ``LIDARD_DEBUG=1`` to get the traceback instead.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, NoReturn

from .errors import ConfigError, LidardError

DEFAULT_URL = "http://127.0.0.1:8470"
EXIT_ERROR = 1
EXIT_USAGE = 2


class CliError(LidardError):
    """A user-facing failure; printed as one line."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) so scripts can parse stderr."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(EXIT_USAGE)


def _emit_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, default=_json_default) + "\n")


def _json_default(o: Any) -> Any:
    import numpy as np
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _open_instrument(cfg, **kw):
    """The composition root (lidard.instrument), imported only when a command needs hardware/sim."""
    try:
        from .instrument import open_instrument
    except ImportError as exc:
        raise CliError(f"the instrument layer is not available ({exc})") from None
    return open_instrument(cfg, **kw)


def _load_config(path: str | None, profile: str | None = None):
    from .config import load_config
    cfg = load_config(path)
    if profile is not None and profile != cfg.profile:
        from .config import Config
        data = cfg.model_dump()
        data.update(profile=profile, lens=None, source=cfg.source, base_dir=cfg.base_dir)
        cfg = Config.model_validate(data)
        cfg.load_profile()
    return cfg


# ---------------------------------------------------------------------------------------- progress
class _ProgressBar:
    """A one-line progress bar on stderr, only when stderr is a terminal."""

    def __init__(self, enabled: bool | None = None, width: int = 30):
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self.width = width
        self._last = ""

    def __call__(self, ev: dict[str, Any]) -> None:
        if not self.enabled or ev.get("event") != "progress":
            return
        frac = float(ev.get("fraction") or 0.0)
        fill = int(round(frac * self.width))
        line = (f"\r{ev.get('stage', ''):>11} [{'#' * fill}{'.' * (self.width - fill)}] {frac * 100:5.1f}% "
                f"{ev.get('pixels_done', 0)}/{ev.get('pixels_planned', 0)} px  {ev.get('points', 0)} pts")
        if line != self._last:
            sys.stderr.write(line)
            sys.stderr.flush()
            self._last = line

    def close(self) -> None:
        if self.enabled and self._last:
            sys.stderr.write("\n")
            sys.stderr.flush()


# -------------------------------------------------------------------------------------- HTTP client
class _Client:
    def __init__(self, url: str, token: str | None, timeout_s: float = 30.0, lease: str | None = None):
        import httpx
        self.url = url.rstrip("/")
        self.lease = lease
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        if lease:  # the control lock (docs/api.md): mutating requests carry the holder's lease
            headers["X-Lidard-Lease"] = lease
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout_s)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "_Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def request(self, method: str, path: str, **kw):
        import httpx
        try:
            r = self._http.request(method, path, **kw)
        except httpx.TransportError as exc:
            raise CliError(f"cannot reach lidard at {self.url} ({type(exc).__name__}: {exc}); "
                           "is the daemon running?") from None
        self._check(r)
        return r

    @staticmethod
    def _check(r) -> None:
        if r.status_code < 400:
            return
        try:
            detail = r.json().get("detail")
        except ValueError:
            detail = r.text.strip()
        if isinstance(detail, list):
            detail = "; ".join(f"{'.'.join(str(x) for x in d.get('loc', [])[1:])}: {d.get('msg')}"
                               for d in detail)
        raise CliError(f"lidard answered {r.status_code}: {detail}")

    def get_json(self, path: str, **kw) -> Any:
        return self.request("GET", path, **kw).json()

    def follow(self, scan_id: str, on_event) -> None:
        """Read the scan's server-sent events until ``end``."""
        import httpx
        try:
            with self._http.stream("GET", f"/scans/{scan_id}/events", timeout=None) as r:
                if r.status_code >= 400:
                    r.read()
                    self._check(r)
                event = None
                for line in r.iter_lines():
                    if line.startswith("event: "):
                        event = line[7:]
                    elif line.startswith("data: ") and event:
                        ev = json.loads(line[6:])
                        on_event(ev)
                        if ev.get("event") == "end":
                            return
        except httpx.TransportError as exc:
            raise CliError(f"lost the connection to lidard at {self.url} ({exc})") from None


def _client(args) -> _Client:
    return _Client(args.url, args.token or os.environ.get("LIDARD_API_TOKEN"),
                   lease=getattr(args, "lease", None) or os.environ.get("LIDARD_LEASE") or None)


def _write_bytes_atomic(path: str | Path, data: bytes) -> None:
    from .pointcloud import atomic_write
    with atomic_write(path) as f:
        f.write(data)


# ------------------------------------------------------------------------------------------ optics
def cmd_optics(args) -> int:
    from .config import load_profile
    profile = load_profile(args.profile)
    s = profile.optics(args.lens).summary()
    s = {"profile": profile.name, "lens": args.lens or profile.default_lens, **s}
    if args.json:
        _emit_json(s)
        return 0
    print(f"profile {s['profile']}, lens {s['lens']} (f = {s['focal_m'] * 1e3:.3g} mm)")
    print(f"  field of view      {s['fov_deg'][0]:8.3f} x {s['fov_deg'][1]:.3f} deg")
    print(f"  resolution         {s['resolution_deg'][0]:8.4f} x {s['resolution_deg'][1]:.4f} deg")
    print(f"  divergence (W/f)   {s['divergence_deg'][0]:8.4f} x {s['divergence_deg'][1]:.4f} deg")
    print(f"  pixels             {s['pixels'][0]} x {s['pixels'][1]} ({s['bonded_rows']} rows bonded)")
    return 0


# ------------------------------------------------------------------------------------------ budget
def cmd_budget(args) -> int:
    from .physics.budget import budget_report
    if not (args.distance > 0):
        raise CliError(f"--distance must be > 0 m, got {args.distance}")
    if args.power is not None and not (args.power > 0):
        raise CliError(f"--power must be > 0 W, got {args.power}")
    cfg = _load_config(args.config, args.profile)
    lp = cfg.link_params()
    if args.power is not None:
        lp = lp.with_(source_power_w=args.power)
    rep = budget_report(lp, args.distance)
    rep = {"profile": cfg.profile, "reference": cfg.link.reference, **rep}
    if args.json:
        _emit_json(rep)
        return 0
    print(f"link budget at {rep['distance_m']:g} m ({cfg.profile}, {cfg.link.reference} reference, "
          f"source {rep['source_power_w'] * 1e3:.3g} mW)")
    print(f"  {'component':<10} {'ASD (V/rtHz)':>14}")
    for k, v in rep["asd_v_per_rthz"].items():
        print(f"  {k:<10} {v:14.4e}")
    print(f"  {'total noise':<10} {rep['noise_total_v_per_rthz']:13.4e}")
    print(f"  SNR {rep['snr_db']:.2f} dB, dominant noise {rep['dominant_noise']}, "
          f"max range {rep['max_range_m']:.4g} m")
    return 0


# -------------------------------------------------------------------------------------------- scan
def _scan_request_dict(args, fmt: str) -> dict[str, Any]:
    def rng(text: str | None, name: str):
        if text is None:
            return None
        try:
            a, b = (int(x) for x in text.split(":"))
        except ValueError:
            raise CliError(f"--{name}: expected A:B (first:stop), got {text!r}") from None
        return [a, b]
    body: dict[str, Any] = {"formats": [fmt]}
    if args.pattern is not None:
        body["pattern"] = args.pattern
    if args.rows is not None:
        body["rows"] = rng(args.rows, "rows")
    if args.cols is not None:
        body["cols"] = rng(args.cols, "cols")
    if body.get("pattern") is None and (args.rows or args.cols):
        body["pattern"] = "roi"
    if args.averages is not None:
        body["averages"] = args.averages
    if args.max_range is not None:
        body["max_range_m"] = args.max_range
    if args.phase_noise is not None:
        body["phase_noise_compensation"] = args.phase_noise
    return body


def _scan_summary(rec: dict[str, Any], out: str | None, simulated: bool) -> dict[str, Any]:
    hw = rec.get("hardware_time_s")
    wall = rec.get("wall_time_s")
    planned = rec.get("pixels_planned") or 0
    return {
        "id": rec["id"], "state": rec["state"], "partial": bool(rec.get("partial")),
        "points": rec.get("points", 0), "out": out, "error": rec.get("error"),
        "hardware_time_s": hw, "wall_time_s": wall,
        "realtime_factor": (hw / wall) if hw is not None and wall else None,
        "coverage": (rec.get("pixels_scanned", 0) / planned) if planned else 0.0,
        "simulated": simulated,
    }


def cmd_scan(args) -> int:
    from .pointcloud import format_of
    fmt = format_of(args.out) if args.out else "ply"
    if args.scene and not args.sim:
        raise CliError("--scene only applies to --sim (a daemon's scene is set with PUT /sim/scene)")
    body = _scan_request_dict(args, fmt)
    bar = _ProgressBar()
    try:
        summary = _scan_sim(args, body, bar) if args.sim else _scan_daemon(args, body, bar)
    finally:
        bar.close()
    if args.json:
        _emit_json(summary)
    else:
        print(f"scan {summary['id']}: {summary['state']}{' (partial)' if summary['partial'] else ''}, "
              f"{summary['points']} points, coverage {summary['coverage'] * 100:.1f} %"
              + (f", written to {summary['out']}" if summary["out"] else ""))
    if summary["state"] not in ("done", "cancelled"):
        raise CliError(f"scan {summary['id']} {summary['state']}: {summary.get('error') or 'no detail'}")
    return 0


def _scan_daemon(args, body: dict[str, Any], bar) -> dict[str, Any]:
    with _client(args) as c:
        rec = c.request("POST", "/scans", json=body).json()
        sid = rec["id"]
        try:
            c.follow(sid, bar)
        except KeyboardInterrupt:
            c.request("DELETE", f"/scans/{sid}")
            c.follow(sid, bar)
        rec = c.get_json(f"/scans/{sid}")
        flat = {"id": rec["id"], "state": rec["state"], "partial": rec["partial"], **rec["counts"],
                "hardware_time_s": rec["timing"]["hardware_time_s"], "wall_time_s": rec["timing"]["wall_time_s"]}
        out = None
        if args.out and rec["formats"]:
            r = c.request("GET", f"/scans/{sid}/points", params={"format": body["formats"][0]})
            _write_bytes_atomic(args.out, r.content)
            out = str(args.out)
        summary = _scan_summary(flat, out, bool(c.get_json("/health").get("simulated")))
        summary["error"] = rec.get("error")
        return summary


@contextlib.contextmanager
def _embedded(args, **open_kw):
    """An embedded simulated instrument with a worker and a store (the daemon's own job path)."""
    from .jobs import ScanWorker
    from .store import Store
    # --sim without --config: the packaged simulated bench configuration
    from .config import CONFIG_DIR
    cfg = _load_config(args.config or str(CONFIG_DIR / "sim.toml"), getattr(args, "profile", None))
    if not cfg.sim.enabled:
        raise CliError(f"--sim needs a simulated configuration; {cfg.source} has sim.enabled = false")
    inst = _open_instrument(cfg, bench="embedded", **open_kw)
    tmp = None
    try:
        data_dir = args.data_dir
        if data_dir is None:
            tmp = tempfile.TemporaryDirectory(prefix="lidarctl-")
            data_dir = tmp.name
        store = Store(data_dir)
        optics = cfg.optics()
        profile = cfg.load_profile()
        meta = {"profile": profile.name, "lens": cfg.lens or profile.default_lens, "laser": cfg.laser,
                "chirp": cfg.chirp.model_dump(), "adc": cfg.adc.model_dump(),
                "detector": cfg.detector.model_dump(), "config": cfg.source}
        worker = ScanWorker(inst, store, laser=cfg.laser, meta=meta, max_queue=1,
                            optics=optics, recalibrate_delta_c=cfg.scan.recalibrate_delta_c)
        worker.start()
        try:
            yield worker, store, inst
        finally:
            worker.stop()
            store.close()
    finally:
        try:
            inst.close()
        finally:
            if tmp is not None:
                tmp.cleanup()


def _scan_sim(args, body: dict[str, Any], bar) -> dict[str, Any]:
    from .jobs import request_from_dict
    from .pointcloud import sidecar_path
    from .scan import ScanPlanError, plan
    req = request_from_dict(body)
    scene = str(Path(args.scene).resolve()) if args.scene else None
    with _embedded(args, scene_path=scene) as (worker, store, inst):
        cfg_optics = _load_config(args.config, args.profile).optics()
        try:
            plan(req, cfg_optics)
        except ScanPlanError as exc:
            raise CliError(str(exc)) from None
        rec = worker.submit_scan(req)
        worker.subscribe(rec.id, bar)
        try:
            final = worker.wait(rec.id)
        except KeyboardInterrupt:
            worker.cancel(rec.id)
            final = worker.wait(rec.id)
        out = None
        fmt = body["formats"][0]
        if args.out and fmt in final.files:
            src = store.data_dir / final.files[fmt]
            _copy_atomic(src, args.out)
            _copy_atomic(sidecar_path(src), sidecar_path(args.out))
            out = str(args.out)
        summary = _scan_summary(final.to_dict(), out, bool(getattr(inst, "simulated", True)))
        summary["error"] = final.error
        return summary


def _copy_atomic(src: Path, dst: str | Path) -> None:
    from .pointcloud import atomic_write
    with open(src, "rb") as fin, atomic_write(dst) as fout:
        shutil.copyfileobj(fin, fout)


# ------------------------------------------------------------------------------- daemon status etc.
def cmd_status(args) -> int:
    with _client(args) as c:
        h = c.get_json("/health")
    if args.json:
        _emit_json(h)
    else:
        print(f"lidard {h['version']} at {args.url}: {h['status']}"
              f"{' (simulated)' if h['simulated'] else ''}; queue {h['queue_length']}, "
              f"running {h['running_scan'] or '-'}")
    return 0


def cmd_devices(args) -> int:
    with _client(args) as c:
        devs = c.get_json("/devices")["devices"]
    if args.json:
        _emit_json({"devices": devs})
        return 0
    for d in devs:
        faults = ", ".join(str(f) for f in d.get("faults") or []) or "-"
        print(f"{d.get('name', '?'):<12} {'connected' if d.get('connected') else 'DISCONNECTED':<13} "
              f"{str(d.get('state', '')):<10} {str(d.get('identity', '')):<30} faults: {faults}")
    return 0


def cmd_scans(args) -> int:
    with _client(args) as c:
        if args.action == "list":
            data = c.get_json("/scans")
            if args.json:
                _emit_json(data)
            else:
                for s in data["scans"]:
                    print(f"{s['id']}  {s['state']:<11} {s['progress'] * 100:5.1f}%  "
                          f"{s['counts']['points']:>8} pts  {s['request'].get('pattern', '')}"
                          f"{'  partial' if s['partial'] else ''}")
        elif args.action == "show":
            if not args.id:
                raise CliError("scans show: give a scan ID")
            _emit_json(c.get_json(f"/scans/{args.id}"))
        else:  # fetch
            if not args.id or not args.out:
                raise CliError("scans fetch: give a scan ID and --out FILE")
            from .pointcloud import format_of
            fmt = args.format or format_of(args.out)
            r = c.request("GET", f"/scans/{args.id}/points", params={"format": fmt})
            _write_bytes_atomic(args.out, r.content)
            if args.json:
                _emit_json({"id": args.id, "out": str(args.out), "bytes": len(r.content)})
            else:
                print(f"wrote {args.out} ({len(r.content)} bytes)")
    return 0


# ----------------------------------------------------------------------------------------- control
def cmd_control(args) -> int:
    """The control lock: ``acquire`` prints the lease (export it as LIDARD_LEASE), ``release``
    gives it back, ``status`` shows the holder."""
    with _client(args) as c:
        if args.action == "acquire":
            import getpass
            import socket
            name = args.client or f"{getpass.getuser()}@{socket.gethostname()}"
            out = c.request("POST", "/control", json={"client": name[:64]}).json()
        elif args.action == "release":
            if not c.lease:
                raise CliError("control release: give the lease with --lease or LIDARD_LEASE")
            out = c.request("DELETE", "/control").json()
        else:
            out = c.get_json("/control")
    if args.json:
        _emit_json(out)
    elif args.action == "acquire":
        print(f"control lock held by {out['holder']} for {out['ttl_s']:g} s after each use; "
              f"export LIDARD_LEASE={out['lease']}")
    elif out.get("held"):
        print(f"control lock held by {out['holder']} (lapses in {out['expires_in_s']:.0f} s unless used)")
    else:
        print("control lock free" + (" (released)" if args.action == "release" else ""))
    return 0


# --------------------------------------------------------------------------------------- linearize
def cmd_linearize(args) -> int:
    if args.sim:
        with _embedded(args) as (worker, store, inst):
            cal = worker.submit_calibration().result()
        iterations, reduction = cal.iterations, cal.reduction
        converged = bool(cal.converged)
    else:
        with _client(args) as c:
            body = c.request("POST", "/calibration/linearize", timeout=None).json()
        iterations, reduction, converged = body["iterations"], body["reduction"], body["converged"]
    its = [{"up_rms_hz": float(it["up_rms_hz"]), "down_rms_hz": float(it["down_rms_hz"])} for it in iterations]
    if args.plot:
        _plot_linearization(its, args.plot)
    if args.json:
        _emit_json({"iterations": its, "reduction": {k: float(v) for k, v in reduction.items()},
                    "converged": converged})
        return 0
    print(f"{'iter':>4} {'up RMS (Hz)':>14} {'down RMS (Hz)':>14}")
    for i, it in enumerate(its):
        print(f"{i:>4} {it['up_rms_hz']:14.4e} {it['down_rms_hz']:14.4e}")
    print("reduction: " + ", ".join(f"{k} {v:.3g}x" for k, v in reduction.items())
          + ("" if converged else " (not converged)"))
    return 0


# ---------------------------------------------------------------------------------------- selftest
EXIT_STUCK = 3   # the self-test ran and found a stuck switch


def cmd_selftest(args) -> int:
    """Toggle every row and column against the monitor tap; exit 3 if a switch is stuck."""
    if args.sim:
        with _embedded(args) as (worker, store, inst):
            report = worker.submit_selftest().result()
    else:
        with _client(args) as c:
            report = c.request("POST", "/selftest", timeout=None).json()
    if args.json:
        _emit_json(report)
    else:
        v1 = report.get("single_beam_v")
        print(f"self-test: {report['rows_tested']} rows (partner column {report['partner_col']}), "
              f"{report['cols_tested']} columns (partner row {report['partner_row']}); "
              f"one beam = {v1:.4g} V at the tap" if isinstance(v1, (int, float)) else "no light at the tap")
        if report["ok"]:
            print("all switches respond: none stuck")
        for st in report["stuck"]:
            print(f"STUCK {st['state'].upper():<3} {st['line']} {st['index']}: {st.get('evidence', '')}")
    return 0 if report["ok"] else EXIT_STUCK


def _plot_linearization(its: list[dict[str, float]], path: str) -> None:
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    n = range(len(its))
    ax.semilogy(n, [it["up_rms_hz"] for it in its], "o-", label="up-ramp")
    ax.semilogy(n, [it["down_rms_hz"] for it in its], "s-", label="down-ramp")
    ax.set_xlabel("ILC iteration")
    ax.set_ylabel("RMS frequency error (Hz)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    _write_bytes_atomic(path, buf.getvalue())


# ------------------------------------------------------------------------------------------ parsers
def build_lidarctl_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="lidarctl", description="Control and inspect an FPSA FMCW LiDAR (lidard).")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def daemon_opts(sp, sim: bool = False):
        sp.add_argument("--url", default=os.environ.get("LIDARD_URL", DEFAULT_URL),
                        help=f"daemon URL (default {DEFAULT_URL} or $LIDARD_URL)")
        sp.add_argument("--token", default=None, help="API token (default $LIDARD_API_TOKEN)")
        sp.add_argument("--lease", default=None, help="control lease to send as X-Lidard-Lease "
                                                      "(default $LIDARD_LEASE; see `lidarctl control`)")
        sp.add_argument("--json", action="store_true", help="print exactly one JSON object")
        if sim:
            sp.add_argument("--sim", action="store_true",
                            help="no daemon: run an embedded simulated bench in this process")
            sp.add_argument("--config", default=None, help="configuration TOML (with --sim)")
            sp.add_argument("--data-dir", default=None,
                            help="with --sim: keep the store (calibrations, scans) here instead of a temp dir")

    sp = sub.add_parser("optics", help="FPSA field of view, resolution, divergence (Table 4-1)")
    sp.add_argument("--profile", required=True)
    sp.add_argument("--lens", default=None)
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(fn=cmd_optics)

    sp = sub.add_parser("budget", help="link budget and SNR at a distance (§2.4.1)")
    sp.add_argument("--profile", default=None, help="scanner profile (default: the config's)")
    sp.add_argument("--distance", type=float, required=True, help="target distance, m")
    sp.add_argument("--power", type=float, default=None, help="source optical power, W")
    sp.add_argument("--config", default=None)
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(fn=cmd_budget)

    sp = sub.add_parser("scan", help="run a scan (on the daemon, or --sim in process)")
    daemon_opts(sp, sim=True)
    sp.add_argument("--profile", default=None, help="scanner profile (with --sim)")
    sp.add_argument("--scene", default=None, help="scene TOML (with --sim)")
    sp.add_argument("--pattern", choices=["raster", "serpentine", "roi", "pixels", "adaptive"], default=None)
    sp.add_argument("--rows", default=None, metavar="A:B", help="rows [A, B)")
    sp.add_argument("--cols", default=None, metavar="A:B", help="columns [A, B)")
    sp.add_argument("--averages", type=int, default=None)
    sp.add_argument("--max-range", type=float, default=None, help="m")
    sp.add_argument("--phase-noise", choices=["auto", "on", "off"], default=None,
                    help="laser phase-noise compensation from the monitor MZI (default: config scan.*)")
    sp.add_argument("--out", default=None, help="output FILE.ply|.las|.npz")
    sp.set_defaults(fn=cmd_scan)

    sp = sub.add_parser("status", help="daemon health")
    daemon_opts(sp)
    sp.set_defaults(fn=cmd_status)

    sp = sub.add_parser("devices", help="per-device state")
    daemon_opts(sp)
    sp.set_defaults(fn=cmd_devices)

    sp = sub.add_parser("scans", help="list, show or fetch stored scans")
    daemon_opts(sp)
    sp.add_argument("action", choices=["list", "show", "fetch"])
    sp.add_argument("id", nargs="?")
    sp.add_argument("--format", choices=["ply", "las", "npz"], default=None)
    sp.add_argument("--out", default=None)
    sp.set_defaults(fn=cmd_scans)

    sp = sub.add_parser("selftest", help="toggle every FPSA row/column, report stuck switches (exit 3)")
    daemon_opts(sp, sim=True)
    sp.set_defaults(fn=cmd_selftest)

    sp = sub.add_parser("linearize", help="run the chirp linearization (ILC)")
    daemon_opts(sp, sim=True)
    sp.add_argument("--plot", default=None, metavar="FILE.png")
    sp.set_defaults(fn=cmd_linearize)

    sp = sub.add_parser("control", help="take, release or show the daemon's control lock")
    daemon_opts(sp)
    sp.add_argument("action", choices=["acquire", "release", "status"])
    sp.add_argument("--client", default=None,
                    help="name shown to other clients (default user@host)")
    sp.set_defaults(fn=cmd_control)
    return p


def _run(fn, args, prog: str) -> int:
    try:
        return fn(args)
    except KeyboardInterrupt:
        sys.stderr.write(f"{prog}: interrupted\n")
        return 130
    except Exception as exc:
        if os.environ.get("LIDARD_DEBUG"):
            raise
        msg = str(exc).replace("\n", " ").strip()
        if isinstance(exc, (CliError, ConfigError)):
            sys.stderr.write(f"{prog}: error: {msg}\n")
        else:
            sys.stderr.write(f"{prog}: error: {type(exc).__name__}: {msg}\n")
        return EXIT_ERROR


def _glue_secret_values(argv: list[str]) -> list[str]:
    """``--lease -Xy`` -> ``--lease=-Xy`` (and ``--token``): a secret may start with "-" (a lease of an
    older daemon, a token the user generated with ``token_urlsafe``), which argparse would otherwise
    take for an option and fail with "expected one argument". ``--lease --json`` stays an error."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if (a in ("--lease", "--token") and i + 1 < len(argv) and argv[i + 1].startswith("-")
                and not argv[i + 1].startswith("--") and argv[i + 1] != "-h"):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def lidarctl_main(argv: list[str] | None = None) -> int:
    argv = _glue_secret_values(list(sys.argv[1:] if argv is None else argv))
    args = build_lidarctl_parser().parse_args(argv)
    return _run(args.fn, args, "lidarctl")


# ------------------------------------------------------------------------------------------ lidard
def is_loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def build_lidard_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="lidard", description="FPSA FMCW LiDAR control daemon (REST API, OpenAPI at /docs).")
    p.add_argument("--config", default=None, help="configuration TOML (e.g. config/sim.toml)")
    p.add_argument("--host", default=None, help="bind address (default from config: 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="port (default from config: 8470)")
    p.add_argument("--data-dir", default=None, help="store directory (default from config)")
    p.add_argument("--token", default=None, help="API token (default $LIDARD_API_TOKEN); "
                                                 "required to bind a non-loopback address")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    return p


def _daemon(args) -> int:
    cfg = _load_config(args.config)
    host = args.host or cfg.daemon.host
    port = cfg.daemon.port if args.port is None else args.port
    if not 0 <= port <= 65535:
        raise CliError(f"--port must be in 0..65535, got {port}")
    token = args.token or os.environ.get("LIDARD_API_TOKEN") or None
    if not is_loopback(host) and not token:
        raise CliError(f"refusing to bind non-loopback address {host}: set an API token "
                       "(--token or LIDARD_API_TOKEN) first")
    data_dir = args.data_dir or cfg.daemon.data_dir
    # Bind before starting the bench or the hardware: a busy port is then one clear line.
    sock = _bind(host, port)
    import uvicorn

    from .api.app import create_app
    try:
        instrument = _open_instrument(cfg)
    except BaseException:
        sock.close()
        raise
    app = create_app(cfg, instrument=instrument, data_dir=data_dir, token=token)
    # an open event stream must not hold shutdown (and the laser/HV power-down) hostage
    server = uvicorn.Server(uvicorn.Config(app, log_level=args.log_level, timeout_graceful_shutdown=5))
    sys.stderr.write(f"lidard: serving on http://{host}:{sock.getsockname()[1]} (OpenAPI at /docs)\n")
    if not is_loopback(host):
        # the daemon speaks plain HTTP: the bearer token crosses the network in clear text
        sys.stderr.write("lidard: warning: plain HTTP on a non-loopback address; the API token is sent in "
                         "clear text, so put a TLS proxy or an SSH tunnel in front for untrusted networks\n")
    server.run(sockets=[sock])
    return 0


def _bind(host: str, port: int):
    import socket
    family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
    # proto must say TCP: asyncio sets TCP_NODELAY on accepted connections only when the socket's
    # proto is IPPROTO_TCP, and with proto 0 Nagle + delayed ACK add ~40 ms to every response
    # (measured: 46 ms -> 0.8 ms per sequential request, benchmarks/load.py).
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host.strip("[]"), port))
        # listen now: a client that connects once "serving on" is printed waits in the backlog
        # until the app has started instead of being refused
        sock.listen(2048)
    except OSError as exc:
        sock.close()
        raise CliError(f"cannot bind {host}:{port}: {exc.strerror or exc}") from None
    sock.set_inheritable(True)
    return sock


def lidard_main(argv: list[str] | None = None) -> int:
    args = build_lidard_parser().parse_args(argv)
    return _run(_daemon, args, "lidard")
