"""Offline work that outgrows one process on Dask: design sweeps, and the cluster layer that `lidarctl reprocess` also uses for raw captures.

Nothing here runs inside the daemon: the daemon stays one process per instrument. This package needs
the ``offline`` extra (dask.distributed, pyarrow); :func:`require_offline_extra` turns a missing
package into one clear error naming the install command instead of an ImportError deep in a task.

Rooms:

* :mod:`lidard.offline.cluster`  start a LocalCluster or connect to a scheduler, run tasks in order,
  report failed tasks with their parameters (reusable by the raw-capture reprocessing);
* :mod:`lidard.offline.spec`     the sweep file (pydantic), its grid expanded into tasks;
* :mod:`lidard.offline.sweep`    the task: the bench's world synthesis + the daemon's DSP for one
  configuration, distance and Monte-Carlo seed (the offline composition root);
* :mod:`lidard.offline.results`  Parquet parts (one row per task), resume, the summary and plots;
* :mod:`lidard.offline.sweep_cli` ``lidarctl sweep``.
"""

from __future__ import annotations

import importlib.util

from lidard.errors import LidardError

INSTALL_HINT = 'pip install -e ".[offline]"'
_EXTRA_MODULES = ("dask", "distributed", "pyarrow")


class OfflineExtraMissing(LidardError):
    """A package of the ``offline`` extra is not installed; the message names it and the fix."""


def require_offline_extra(modules: tuple[str, ...] = _EXTRA_MODULES) -> None:
    """Raise :class:`OfflineExtraMissing` naming every missing package and the install command."""
    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise OfflineExtraMissing(
            f"lidarctl sweep needs the offline extra (missing: {', '.join(missing)}); "
            f"install it with: {INSTALL_HINT}")
