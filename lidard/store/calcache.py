"""A per-user cache of chirp linearizations for one-shot ``--sim`` commands.

A ``lidarctl scan --sim`` without ``--data-dir`` runs on a temporary store, so without this cache
every run would linearize the chirp again (ILC, dissertation §2.2: seconds of work for the same
result). The cache keeps the newest calibration per configuration key in
``$XDG_CACHE_HOME/lidard/calibrations`` (default ``~/.cache/lidard``). The key hashes what the
linearization depends on: the configuration without the sections that only shape a scan or the
daemon (``scan``, ``daemon``, ``live``, the scene), the laser preset's own values (editing
``lasers.toml`` invalidates it) and this cache's format version.

The laser temperature is not part of the key: a cached calibration is seeded into the temporary
store, and the scan worker's own checks (``scan.recalibrate_delta_c`` and the linearization health
check, ``scan.linearity_threshold_hz``; lidard.jobs) re-linearize when the TEC temperature moved
further than that or the chirp measured before the scan is off; the new calibration then replaces
the entry.
With ``--data-dir`` the store itself keeps calibrations and this cache is not used.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np

from ..instrument.types import CalibrationResult

log = logging.getLogger(__name__)

# 2: a three-segment linearization carries the held segment's measured drift (meta["hold_profile"])
FORMAT_VERSION = 2
# config sections that shape a scan or the daemon, never the linearized drive waveform
_NOT_IN_KEY = ("scan", "daemon", "live", "path")


def cache_dir(environ: dict[str, str] | None = None) -> Path:
    """``$XDG_CACHE_HOME/lidard`` or ``~/.cache/lidard``."""
    env = os.environ if environ is None else environ
    base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "lidard"


def config_key(cfg) -> str:
    """Hex digest of what a linearization of ``cfg`` depends on."""
    data = cfg.model_dump(mode="json")
    for k in _NOT_IN_KEY:
        data.pop(k, None)
    data.get("sim", {}).pop("scene", None)
    data["laser_preset"] = cfg.resolved.laser.model_dump(mode="json")
    data["cache_format"] = FORMAT_VERSION
    blob = json.dumps(data, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:32]


def _path(cfg, root: Path | None) -> Path:
    return (root or cache_dir()) / "calibrations" / f"{config_key(cfg)}.npz"


def load(cfg, root: Path | None = None) -> CalibrationResult | None:
    """The cached calibration of ``cfg``'s key, or None (missing or unreadable: logged, ignored)."""
    path = _path(cfg, root)
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            fields = json.loads(str(z["fields"]))
            drive = np.array(z["drive_v"], dtype=np.float64)
        return CalibrationResult(drive_v=drive, **fields)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("calibration cache %s unreadable (%s); linearizing again", path, exc)
        return None


def _write_atomic(path: Path, write) -> Path | None:
    """``write(file)`` into a temporary file beside ``path``, then rename it over ``path``; None (and a
    warning) if it could not be written: a cache that cannot be written is no reason to fail a scan."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            write(f)
        os.replace(tmp, path)
        return path
    except OSError as exc:
        log.warning("calibration cache %s not written (%s)", path, exc)
        tmp.unlink(missing_ok=True)
        return None


def save(cfg, cal: CalibrationResult, root: Path | None = None) -> Path | None:
    """Store ``cal`` as the entry of ``cfg``'s key (atomic rename); None if it could not be written."""
    fields = {"iterations": cal.iterations, "reduction": cal.reduction, "converged": bool(cal.converged),
              "laser": cal.laser, "temperature_c": float(cal.temperature_c),
              "fs_drive_hz": float(cal.fs_drive_hz), "meta": cal.meta}
    return _write_atomic(_path(cfg, root), lambda f: np.savez(
        f, drive_v=np.asarray(cal.drive_v, dtype=np.float64), fields=np.array(json.dumps(fields, default=str))))


# -- range / pointing calibration records (the simulated bench's factory calibration) -----------------
# Kept apart from the linearizations above: their key is the set-up the records are tied to
# (lidard.instrument.calibration.setup.CalibrationSetup.hash), not the linearization's configuration key.
RECORDS_FORMAT_VERSION = 1


def _records_path(setup_hash: str, root: Path | None) -> Path:
    return (root or cache_dir()) / "geometry" / f"{setup_hash}.v{RECORDS_FORMAT_VERSION}.json"


def load_records(setup_hash: str, root: Path | None = None) -> list[dict] | None:
    """The cached calibration records (``CalibrationRecord.to_dict()``) of a set-up, or None."""
    path = _records_path(setup_hash, root)
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
        recs = data["records"]
        if not isinstance(recs, list) or not all(isinstance(r, dict) and "kind" in r for r in recs):
            raise ValueError("not a list of records")
        return recs
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("calibration cache %s unreadable (%s); calibrating again", path, exc)
        return None


def save_records(setup_hash: str, records: list[dict], root: Path | None = None) -> Path | None:
    """Keep ``records`` as the entry of ``setup_hash`` (atomic rename); None if it could not be written."""
    body = json.dumps({"setup": setup_hash, "records": records}, default=str).encode()
    return _write_atomic(_records_path(setup_hash, root), lambda f: f.write(body))
