"""``lidarctl``: the client of a running lidard and the offline tools, one module per command group.

A new command goes in its own module of this package with an ``add_parser(sub)`` that registers it
and sets ``fn``; list it in :data:`GROUPS` below.
"""

from __future__ import annotations

import argparse
import sys

from . import (calibrate, calibration, control, devices, faults, guided, optics, raw, scan, scans, selftest, sim,
               stream, sweep)
from .base import Parser, run, stop_signals

# (module, registering function) in the order ``lidarctl --help`` lists them
GROUPS = ((scan, "add_parser"), (devices, "add_parsers"), (scans, "add_parser"), (control, "add_parser"),
          (faults, "add_parser"), (calibration, "add_parser"), (calibrate, "add_parser"), (guided, "add_parser"),
          (selftest, "add_parser"),
          (optics, "add_parsers"), (raw, "add_parsers"), (sweep, "add_parser"),
          (sim, "add_parser"), (stream, "add_parser"))

DESCRIPTION = """\
Control and inspect an FPSA FMCW LiDAR through its daemon (lidard), or run it on an embedded
simulated bench with --sim. `lidarctl COMMAND --help` explains each command."""


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="lidarctl", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module, register in GROUPS:
        getattr(module, register)(sub)
    return p


def glue_secret_values(argv: list[str]) -> list[str]:
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


def main(argv: list[str] | None = None) -> int:
    argv = glue_secret_values(list(sys.argv[1:] if argv is None else argv))
    args = build_parser().parse_args(argv)
    # SIGTERM and SIGHUP stop a command as Ctrl-C does (lidard.cli.base): a one-shot scan keeps its
    # points and removes its temporary store instead of dying where it stands
    with stop_signals():
        return run(args.fn, args, "lidarctl")
