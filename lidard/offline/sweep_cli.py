"""``lidarctl sweep SWEEP.toml``: a design sweep on a local Dask cluster or an existing scheduler.

``add_parser(sub)`` registers the command in a ``lidarctl`` subparser set (its ``fn`` is
:func:`cmd_sweep`); :func:`sweep_main` runs it standalone. Exit status: 0 all tasks done, 1 some
tasks failed (each printed with its parameters; a rerun retries only those), 2 bad input or a
missing ``offline`` extra, 130 interrupted (rows already written are kept: rerun to resume).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lidard.errors import LidardError

EXIT_FAILED_TASKS = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130

HELP = "design sweep (configurations x targets x seeds) on Dask; Parquet, summary and plots"


def _configure(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("spec", metavar="SWEEP.toml", help="the sweep file (format: docs/scale-out.md)")
    sp.add_argument("--out", default=None, metavar="DIR",
                    help="output directory (default: sweeps/<sweep name> under the current directory); "
                         "a rerun into the same directory skips finished tasks")
    where = sp.add_mutually_exclusive_group()
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="an existing dask.distributed scheduler, e.g. tcp://10.0.0.5:8786 "
                            "(default: start a LocalCluster of worker processes)")
    where.add_argument("--in-process", action="store_true",
                       help="run every task in this process, without Dask (baseline; debugging)")
    sp.add_argument("--workers", type=int, default=None, metavar="N",
                    help="worker processes of the LocalCluster (default: the CPU count)")
    sp.add_argument("--batch", type=int, default=8, metavar="N",
                    help="sweep tasks per Dask task (default 8: a task is tens of ms, Dask's own cost a few ms "
                         "per task; see docs/sweeps.md)")
    sp.add_argument("--no-plot", action="store_true", help="skip the plots (summary.csv is still written)")
    sp.add_argument("--dry-run", action="store_true", help="validate and count the tasks, run nothing")


def add_parser(sub) -> argparse.ArgumentParser:
    sp = sub.add_parser("sweep", help=HELP, description=HELP)
    _configure(sp)
    sp.set_defaults(fn=cmd_sweep)
    return sp


def build_sweep_parser() -> argparse.ArgumentParser:
    sp = argparse.ArgumentParser(prog="lidarctl sweep", description=HELP)
    _configure(sp)
    return sp


class _Progress:
    """One line on stderr, rewritten in place on a terminal, every 10 % otherwise."""

    def __init__(self, stream=sys.stderr) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self.t0 = time.monotonic()
        self._last_decile = -1

    def __call__(self, done: int, total: int, failed: int) -> None:
        rate = done / max(time.monotonic() - self.t0, 1e-9)
        line = f"sweep: {done}/{total} tasks, {failed} failed, {rate:.1f} tasks/s"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done == total else ""))
        elif done * 10 // max(total, 1) != self._last_decile or done == total:
            self._last_decile = done * 10 // max(total, 1)
            self.stream.write(line + "\n")
        self.stream.flush()


def cmd_sweep(args) -> int:
    from . import require_offline_extra
    try:
        require_offline_extra()
        from .runner import run_sweep
        from .spec import load_sweep
        sweep = load_sweep(args.spec)
        if args.workers is not None and args.workers < 1:
            raise LidardError(f"--workers must be >= 1, got {args.workers}")
        if args.batch < 1:
            raise LidardError(f"--batch must be >= 1, got {args.batch}")
        out = Path(args.out) if args.out else Path("sweeps") / sweep.name
        print(f"sweep {sweep.name}: {len(sweep.points)} configurations, {len(sweep.tasks)} tasks -> {out}")
        if args.dry_run:
            return 0
        outcome = run_sweep(sweep, out, scheduler=args.scheduler, workers=args.workers,
                            in_process=args.in_process, on_progress=_Progress(), plot=not args.no_plot,
                            batch_size=args.batch)
    except KeyboardInterrupt:
        sys.stderr.write("lidarctl sweep: interrupted; finished rows are kept, rerun to resume\n")
        return EXIT_INTERRUPTED
    except LidardError as exc:
        sys.stderr.write(f"lidarctl sweep: error: {exc}\n")
        return EXIT_ERROR
    print(f"ran {outcome.ran} tasks ({outcome.skipped} already done) in {outcome.elapsed_s:.1f} s "
          f"on {outcome.workers or 'no'} Dask workers")
    print(outcome.table)
    for w in outcome.warnings:
        sys.stderr.write(f"lidarctl sweep: warning: {w}\n")
    print(f"rows: {out / 'parts'}  summary: {out / 'summary.csv'}" + (f"  plot: {outcome.plot}" if outcome.plot else ""))
    for f in outcome.failures:
        sys.stderr.write(f"lidarctl sweep: FAILED {f.summary()}\n")
    if outcome.failures:
        sys.stderr.write(f"lidarctl sweep: {len(outcome.failures)} tasks failed (see {out / 'failures.json'}); "
                         "a rerun retries only them\n")
        return EXIT_FAILED_TASKS
    return 0


def sweep_main(argv: list[str] | None = None) -> int:
    args = build_sweep_parser().parse_args(sys.argv[1:] if argv is None else argv)
    return cmd_sweep(args)


if __name__ == "__main__":
    raise SystemExit(sweep_main())
