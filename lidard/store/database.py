"""Persistent state of the daemon: scans and chirp calibrations in SQLite, arrays in files.

Layout under the data directory::

    lidard.sqlite3                  WAL mode; tables ``scans`` and ``calibrations``
    scans/<id>/scan.<fmt>[.json]    point clouds and sidecars (written by lidard.jobs)
    scans/<id>/raw.zarr/            the digitizer's raw segments of a scan with record_raw (lidard.raw)
    calibrations/<id>.npy           the linearized drive waveform u(t) of §2.2 (ILC, Fig. 2-5)

Range and pointing calibrations (and the plates measured for the next range fit) are in tables of
their own, kept by ``Store.geometry`` (:class:`lidard.store.geometry.GeometryCalibrations`, which shares
the store's connection and lock).

One connection guarded by a lock serves all threads (the scan worker and the API's threadpool);
SQLite in WAL mode lets outside readers (``sqlite3`` shell, a second daemon refusing to start) read
while the daemon writes. A scan left ``queued`` or ``running`` by a process that died is marked
``interrupted`` when the store is opened again: its hardware state is unknown, so it is never
resumed silently. Temporary files of an interrupted atomic write (``.<name>.<random>.tmp``) are
removed at the same moment: they were never renamed into place, so nothing refers to them.

Memory: SQLite keeps every page it reads or writes in its page cache up to ``cache_size``; as the
scans table grows by a row a scan (about 0.4-0.6 kB of pages with its index entries), that cache
grows with it until its bound, so the daemon's memory rises in a straight line for hours before it
levels off. SQLite's default bound (2000 KiB, reached after about 4,800 scans) is set explicitly
smaller, :data:`PAGE_CACHE_KIB`: the queries the daemon runs (a scan by id, the newest scans, the
newest calibrations) read a few pages of an index each, and a missed page comes from the OS's cache.

Scan ids are 16 characters of Crockford base32: 10 for the millisecond timestamp (so ids sort by
creation time) and 6 random, URL-safe and short enough to type.
"""

from __future__ import annotations

import fcntl
import json
import os
import secrets
import shutil
import sqlite3
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidardError
from ..instrument.types import CalibrationResult
from ..outputs import atomic_write
from .geometry import GEOMETRY_SCHEMA, GeometryCalibrations

SCAN_STATES = ("queued", "running", "done", "failed", "cancelled", "interrupted")
TERMINAL_STATES = frozenset({"done", "failed", "cancelled", "interrupted"})
_CROCKFORD = "0123456789ABCDEFGHJKMNPQRSTVWXYZ"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS scans (
    id TEXT PRIMARY KEY,
    state TEXT NOT NULL,
    request TEXT NOT NULL,
    progress REAL NOT NULL DEFAULT 0,
    stage TEXT NOT NULL DEFAULT 'queued',
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    hardware_time_s REAL,
    wall_time_s REAL,
    points INTEGER NOT NULL DEFAULT 0,
    pixels_scanned INTEGER NOT NULL DEFAULT 0,
    pixels_planned INTEGER NOT NULL DEFAULT 0,
    error TEXT,
    partial INTEGER NOT NULL DEFAULT 0,
    files TEXT NOT NULL DEFAULT '{}',
    calibration_id TEXT,
    raw_bytes INTEGER,
    reprocessed_from TEXT
);
CREATE TABLE IF NOT EXISTS calibrations (
    id TEXT PRIMARY KEY,
    laser TEXT NOT NULL,
    temperature_c REAL,
    created REAL NOT NULL,
    converged INTEGER NOT NULL,
    iterations TEXT NOT NULL,
    reduction TEXT NOT NULL,
    fs_drive_hz REAL NOT NULL,
    drive_file TEXT,
    meta TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS calibrations_laser ON calibrations (laser, created);
"""


_id_lock = threading.Lock()
_last_id_value = 0


class StoreError(LidardError):
    """The data directory or database cannot be used; the message names the path."""


class DataDirLocked(StoreError):
    """Another process (a daemon or a one-shot ``lidarctl scan --sim``) holds the data directory."""


LOCK_NAME = "lidard.lock"


def _lock_data_dir(data_dir: Path) -> int:
    """Take the OS lock that makes a process the one owner of ``data_dir`` (``flock``: released by
    the kernel when the process dies, so a ``kill -9`` never leaves a stale lock). The holder's PID is
    written into the lock file so that a refused second process can name it."""
    path = data_dir / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        os.close(fd)
        raise DataDirLocked(
            f"data directory {data_dir} is in use by another lidard process (PID {holder}); "
            "stop it or choose another --data-dir") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def new_id(now_s: float | None = None) -> str:
    """Short, URL-safe, time-sortable id: 48-bit ms timestamp + 30 random bits, Crockford base32."""
    global _last_id_value
    ms = int((time.time() if now_s is None else now_s) * 1000)
    value = (ms << 30) | secrets.randbits(30)
    with _id_lock:
        # Two ids in the same millisecond still sort in creation order within this process.
        if value <= _last_id_value:
            value = _last_id_value + 1
        _last_id_value = value
    chars = []
    for _ in range(16):
        chars.append(_CROCKFORD[value & 31])
        value >>= 5
    return "".join(reversed(chars))


@dataclass
class ScanRecord:
    id: str
    state: str
    request: dict[str, Any]
    progress: float = 0.0
    stage: str = "queued"
    created: float = 0.0
    started: float | None = None
    finished: float | None = None
    hardware_time_s: float | None = None
    wall_time_s: float | None = None
    points: int = 0
    pixels_scanned: int = 0
    pixels_planned: int = 0
    error: str | None = None
    partial: bool = False
    files: dict[str, str] = field(default_factory=dict)
    calibration_id: str | None = None
    raw_bytes: int | None = None          # size of scans/<id>/raw.zarr (record_raw), None without one
    reprocessed_from: str | None = None   # the scan whose raw capture this one was computed from
    range_calibration_id: str | None = None      # the range scale/zero calibration the scan used
    pointing_calibration_id: str | None = None   # the pointing calibration the scan used
    receiver: str | None = None                  # "real" (one photodiode) or "iq" (adc.iq)
    iq_calibration_id: str | None = None         # the I/Q imbalance calibration the scan used
    uncalibrated_reason: str | None = None       # why stored calibrations were not used (another set-up)

    @property
    def calibrated(self) -> dict[str, bool]:
        """Which calibrations the scan used (uncalibrated is said, not hidden); an
        I/Q receiver's scan also says whether its imbalance was calibrated."""
        out = {"range": self.range_calibration_id is not None,
               "pointing": self.pointing_calibration_id is not None,
               "linearization": self.calibration_id is not None}
        if self.receiver == "iq":
            out["iq"] = self.iq_calibration_id is not None
        return out

    @property
    def terminal(self) -> bool:
        return self.state in TERMINAL_STATES

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


_SCAN_COLUMNS = tuple(ScanRecord.__dataclass_fields__)
_JSON_COLUMNS = {"request", "files"}
# columns added after the first release: a data directory made before gets them on open
# the bound of SQLite's page cache per connection, KiB (``PRAGMA cache_size`` = -PAGE_CACHE_KIB): the
# store's share of the daemon's memory once its database is larger than this
PAGE_CACHE_KIB = 512

_ADDED_COLUMNS = {"raw_bytes": "INTEGER", "reprocessed_from": "TEXT", "range_calibration_id": "TEXT",
                  "pointing_calibration_id": "TEXT", "receiver": "TEXT", "iq_calibration_id": "TEXT",
                  "uncalibrated_reason": "TEXT"}


class Store:
    """SQLite + files under ``data_dir``; thread-safe (one connection, one lock).

    ``geometry`` keeps the range and pointing calibrations over the same connection and lock."""

    def __init__(self, data_dir: str | os.PathLike):
        self.data_dir = Path(data_dir).expanduser()
        try:
            (self.data_dir / "scans").mkdir(parents=True, exist_ok=True)
            (self.data_dir / "calibrations").mkdir(parents=True, exist_ok=True)
            # Before anything is read or changed: only the lock's holder may mark another
            # process's running scans interrupted.
            self._lock_fd: int | None = _lock_data_dir(self.data_dir)
            self.db_path = self.data_dir / "lidard.sqlite3"
            self._conn = sqlite3.connect(self.db_path, check_same_thread=False, isolation_level=None,
                                         timeout=10.0)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"data directory {self.data_dir}: cannot open the store ({exc})") from None
        self._lock = threading.RLock()
        with self._lock:
            self._conn.row_factory = sqlite3.Row
            mode = self._conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StoreError(f"{self.db_path}: cannot switch SQLite to WAL mode (got {mode})")
            self._conn.execute("PRAGMA synchronous=NORMAL")
            self._conn.execute(f"PRAGMA cache_size=-{PAGE_CACHE_KIB}")
            self._conn.executescript(_SCHEMA + GEOMETRY_SCHEMA)
            have = {r["name"] for r in self._conn.execute("PRAGMA table_info(scans)")}
            for col, typ in _ADDED_COLUMNS.items():
                if col not in have:
                    self._conn.execute(f"ALTER TABLE scans ADD COLUMN {col} {typ}")
            cut = [r["id"] for r in self._conn.execute("SELECT id FROM scans WHERE state IN ('queued', 'running')")]
            self.recovered = self._conn.execute(
                "UPDATE scans SET state='interrupted', stage='interrupted', "
                "error=COALESCE(error, 'daemon stopped while the scan was ' || state) "
                "WHERE state IN ('queued', 'running')").rowcount
        self.geometry = GeometryCalibrations(self._conn, self._lock, new_id)
        self.swept_tmp = self._sweep_temp_files()
        for scan_id in cut:   # a killed scan's raw capture keeps its committed prefix: count it
            raw = self.scan_dir(scan_id) / "raw.zarr"
            if raw.is_dir():
                self.update_scan(scan_id, raw_bytes=sum(f.stat().st_size for f in raw.rglob("*") if f.is_file()))

    def _sweep_temp_files(self) -> int:
        """Remove temporary files a killed process left behind (``atomic_write``'s ``.<name>.*.tmp``):
        they were never renamed into place, so no record points at them and they hold no data."""
        n = 0
        # zarr's LocalStore (raw captures) writes <key>.<uuid>.partial and renames it the same way
        leftovers = [p for sub in ("scans", "calibrations") for p in (self.data_dir / sub).rglob(".*.tmp")]
        leftovers += list((self.data_dir / "scans").glob("*/raw.zarr/**/*.partial"))
        for p in leftovers:
            try:
                p.unlink()
                n += 1
            except OSError:
                pass
        return n

    # -- lifecycle -----------------------------------------------------------------------------
    def close(self) -> None:
        with self._lock:
            self._conn.close()
            if self._lock_fd is not None:
                os.close(self._lock_fd)   # releases the flock
                self._lock_fd = None

    def journal_mode(self) -> str:
        with self._lock:
            return str(self._conn.execute("PRAGMA journal_mode").fetchone()[0]).lower()

    def scan_dir(self, scan_id: str) -> Path:
        return self.data_dir / "scans" / scan_id

    # -- scans ---------------------------------------------------------------------------------
    def create_scan(self, request: dict[str, Any], pixels_planned: int = 0) -> ScanRecord:
        rec = ScanRecord(id=new_id(), state="queued", request=request, created=time.time(),
                         pixels_planned=pixels_planned)
        with self._lock:
            self._conn.execute(
                "INSERT INTO scans (id, state, request, created, pixels_planned, stage) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (rec.id, rec.state, json.dumps(request), rec.created, pixels_planned, rec.stage))
        return rec

    def update_scan(self, scan_id: str, **fields: Any) -> None:
        bad = set(fields) - set(_SCAN_COLUMNS) - {"id"}
        if bad or "id" in fields:
            raise StoreError(f"update_scan: unknown column(s) {sorted(bad | ({'id'} & set(fields)))}")
        if "state" in fields and fields["state"] not in SCAN_STATES:
            raise StoreError(f"update_scan: state {fields['state']!r} not one of {SCAN_STATES}")
        values = [json.dumps(v) if k in _JSON_COLUMNS else (int(v) if k == "partial" else v)
                  for k, v in fields.items()]
        sets = ", ".join(f"{k} = ?" for k in fields)
        with self._lock:
            cur = self._conn.execute(f"UPDATE scans SET {sets} WHERE id = ?", (*values, scan_id))
        if cur.rowcount != 1:
            raise StoreError(f"scan {scan_id!r} not found")

    def transition(self, scan_id: str, from_states: tuple[str, ...], **fields: Any) -> bool:
        """Update only if the scan is in one of ``from_states`` (atomic compare-and-set)."""
        values = [json.dumps(v) if k in _JSON_COLUMNS else (int(v) if k == "partial" else v)
                  for k, v in fields.items()]
        sets = ", ".join(f"{k} = ?" for k in fields)
        marks = ", ".join("?" for _ in from_states)
        with self._lock:
            cur = self._conn.execute(f"UPDATE scans SET {sets} WHERE id = ? AND state IN ({marks})",
                                     (*values, scan_id, *from_states))
        return cur.rowcount == 1

    @staticmethod
    def _scan_from_row(row: sqlite3.Row) -> ScanRecord:
        d = {k: row[k] for k in _SCAN_COLUMNS}
        d["request"] = json.loads(d["request"])
        d["files"] = json.loads(d["files"])
        d["partial"] = bool(d["partial"])
        return ScanRecord(**d)

    def remove_raw(self, scan_id: str, raw_dir: Path) -> bool:
        """Delete a scan's raw capture directory and forget its size; True when there was one."""
        existed = raw_dir.exists()
        if existed:
            shutil.rmtree(raw_dir)
        self.update_scan(scan_id, raw_bytes=None)
        return existed

    def delete_scan(self, scan_id: str) -> bool:
        """Delete a finished scan: its record and everything under ``scans/<id>/`` (point clouds,
        sidecars, raw capture). A queued or running scan is refused (cancel it first)."""
        rec = self.get_scan(scan_id)
        if rec is None:
            return False
        if not rec.terminal:
            raise StoreError(f"scan {scan_id} is {rec.state}; cancel it before deleting it")
        d = self.scan_dir(scan_id)
        if d.exists():
            shutil.rmtree(d)
        with self._lock:
            self._conn.execute("DELETE FROM scans WHERE id = ?", (scan_id,))
        return True

    def get_scan(self, scan_id: str) -> ScanRecord | None:
        with self._lock:
            row = self._conn.execute("SELECT * FROM scans WHERE id = ?", (scan_id,)).fetchone()
        return None if row is None else self._scan_from_row(row)

    def list_scans(self, limit: int = 100, state: str | None = None) -> list[ScanRecord]:
        """Newest first."""
        q, args = "SELECT * FROM scans", list[str | int]()
        if state is not None:
            q += " WHERE state = ?"
            args.append(state)
        q += " ORDER BY created DESC, id DESC LIMIT ?"
        args.append(int(limit))
        with self._lock:
            rows = self._conn.execute(q, args).fetchall()
        return [self._scan_from_row(r) for r in rows]

    # -- calibrations --------------------------------------------------------------------------
    def save_calibration(self, cal: CalibrationResult, cal_id: str | None = None) -> str:
        """Store ``cal``; ``cal_id`` keeps an id given elsewhere (a calibration from the user's cache)."""
        cal_id = cal_id or new_id()
        drive_file = None
        drive = np.asarray(cal.drive_v, dtype=np.float64)
        if drive.size:
            drive_file = f"calibrations/{cal_id}.npy"
            with atomic_write(self.data_dir / drive_file) as f:
                np.save(f, drive, allow_pickle=False)
        with self._lock:
            self._conn.execute(
                "INSERT INTO calibrations (id, laser, temperature_c, created, converged, iterations, "
                "reduction, fs_drive_hz, drive_file, meta) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (cal_id, cal.laser, float(cal.temperature_c), time.time(), int(bool(cal.converged)),
                 json.dumps(cal.iterations), json.dumps(cal.reduction), float(cal.fs_drive_hz),
                 drive_file, json.dumps(cal.meta, default=str)))
        return cal_id

    def _calibration_from_row(self, row: sqlite3.Row) -> CalibrationResult:
        drive = np.zeros(0)
        if row["drive_file"]:
            drive = np.load(self.data_dir / row["drive_file"], allow_pickle=False)
        meta = json.loads(row["meta"])
        meta.update(id=row["id"], created=row["created"])
        return CalibrationResult(iterations=json.loads(row["iterations"]),
                                 reduction=json.loads(row["reduction"]), converged=bool(row["converged"]),
                                 laser=row["laser"], temperature_c=row["temperature_c"], drive_v=drive,
                                 fs_drive_hz=row["fs_drive_hz"], meta=meta)

    def latest_calibration(self, laser: str | None = None) -> CalibrationResult | None:
        """Newest calibration (for ``laser`` if given); ``meta['id']`` holds its id."""
        q = "SELECT * FROM calibrations"
        args: list[Any] = []
        if laser is not None:
            q += " WHERE laser = ?"
            args.append(laser)
        with self._lock:
            row = self._conn.execute(q + " ORDER BY created DESC, id DESC LIMIT 1", args).fetchone()
        return None if row is None else self._calibration_from_row(row)

    def list_calibrations(self, limit: int = 5, laser: str | None = None) -> list[CalibrationResult]:
        """The newest ``limit`` calibrations (of ``laser`` if given), newest first."""
        q, args = "SELECT * FROM calibrations", []
        if laser is not None:
            q += " WHERE laser = ?"
            args.append(laser)
        with self._lock:
            rows = self._conn.execute(q + " ORDER BY created DESC, id DESC LIMIT ?", [*args, int(limit)]).fetchall()
        return [self._calibration_from_row(r) for r in rows]

    def get_calibration(self, cal_id: str) -> CalibrationResult | None:
        with self._lock:
            row = self._conn.execute("SELECT * FROM calibrations WHERE id = ?", (cal_id,)).fetchone()
        return None if row is None else self._calibration_from_row(row)
