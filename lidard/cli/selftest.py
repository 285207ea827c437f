"""``lidarctl selftest``: toggle every FPSA row and column against the monitor tap (dissertation
§4.3.3, switch yield) and exit 3 if a switch is stuck."""

from __future__ import annotations

from . import output
from .base import EXIT_STUCK
from .client import client, daemon_opts, refuse_sim_only


def add_parser(sub) -> None:
    sp = sub.add_parser("selftest", help="toggle every FPSA row/column, report stuck switches (exit 3)")
    daemon_opts(sp, sim=True)
    sp.set_defaults(fn=cmd_selftest)


def cmd_selftest(args) -> int:
    refuse_sim_only(args, "--config", "--data-dir", "--no-cal-cache")
    if args.sim:
        from .embedded import embedded
        with embedded(args) as (worker, store, inst):
            report = worker.submit_selftest().result()
    else:
        with client(args) as c:
            report = c.request("POST", "/selftest", timeout=None).json()
    if args.json:
        output.emit_json(report)
    else:
        v1 = report.get("single_beam_v")
        print(f"self-test: {report['rows_tested']} rows (partner column {report['partner_col']}), "
              f"{report['cols_tested']} columns (partner row {report['partner_row']}); "
              f"one beam = {v1:.4g} V at the tap" if isinstance(v1, (int, float)) else "no light at the tap")
        if report["ok"]:
            print("all switches respond: none stuck")
        for st in report["stuck"]:
            print(f"STUCK {st['state'].upper():<3} {st['line']} {st['index']}: {st.get('evidence', '')}")
        if report.get("hv_problem"):
            print(f"HV: {report['hv_problem']}")
    return 0 if report["ok"] else EXIT_STUCK
