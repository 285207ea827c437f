"""``lidarctl sweep SWEEP.toml``: design sweeps on a local Dask cluster or an existing scheduler.

The command lives with the rest of the offline tooling in :mod:`lidard.offline.sweep_cli` (its
parser, exit statuses and the missing-extra message); this module only registers it here. Nothing
heavy is imported until the command runs: ``lidarctl --help`` needs neither dask nor pyarrow.
"""

from __future__ import annotations

from ..offline.sweep_cli import add_parser, cmd_sweep

__all__ = ["add_parser", "cmd_sweep"]
