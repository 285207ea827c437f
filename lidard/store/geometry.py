"""The store's records of the geometric calibrations (range scale/zero, pointing).

:class:`GeometryCalibrations` is held by :class:`lidard.store.Store` as ``store.geometry``: it shares
the store's SQLite connection and lock (given to it, not reached for) and keeps two tables:

* ``geometry_calibrations``: one row per accepted fit: id, kind (``range`` | ``pointing``), time, the
  laser TEC temperature when it was made, its inputs (the plate measurements, the target geometry),
  the fitted values and the residuals (JSON);
* ``range_measurements``: the plates measured so far for the next range fit, kept in the database so
  that a daemon restart between ``calibration range add`` and ``calibration range fit`` loses nothing;
  a successful fit consumes them.

The chirp linearizations (§2.2) stay in the ``calibrations`` table of :class:`lidard.store.Store`.
"""

from __future__ import annotations

import json
import math
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Literal

GeometryKind = Literal["range", "pointing"]
GEOMETRY_KINDS = ("range", "pointing", "iq")

GEOMETRY_SCHEMA = """
CREATE TABLE IF NOT EXISTS geometry_calibrations (
    id TEXT PRIMARY KEY,
    kind TEXT NOT NULL,
    created REAL NOT NULL,
    temperature_c REAL,
    inputs TEXT NOT NULL,
    fitted TEXT NOT NULL,
    residuals TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS geometry_calibrations_kind ON geometry_calibrations (kind, created);
CREATE TABLE IF NOT EXISTS range_measurements (
    id TEXT PRIMARY KEY,
    created REAL NOT NULL,
    data TEXT NOT NULL
);
"""


@dataclass(frozen=True)
class CalibrationRecord:
    id: str
    kind: str
    created: float
    temperature_c: float | None
    inputs: dict[str, Any]
    fitted: dict[str, Any]
    residuals: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _clean(value: Any) -> Any:
    # NaN (an unreadable TEC temperature, a p-value with no degrees of freedom) is not JSON: null
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def _json(value: Any) -> str:
    return json.dumps(_clean(value), default=str, allow_nan=False)


class GeometryCalibrations:
    """The geometric calibrations and the pending range measurements of one store.

    ``conn`` and ``lock`` are the store's (one connection guarded by one lock serves every thread);
    ``new_id`` makes the records' ids (time-sortable, as the scans')."""

    def __init__(self, conn: sqlite3.Connection, lock: threading.RLock, new_id: Callable[[], str]):
        self._conn = conn
        self._lock = lock
        self._new_id = new_id

    def save(self, kind: str, *, temperature_c: float | None, inputs: dict[str, Any],
             fitted: dict[str, Any], residuals: dict[str, Any]) -> CalibrationRecord:
        if kind not in GEOMETRY_KINDS:
            raise ValueError(f"calibration kind {kind!r} is not one of {GEOMETRY_KINDS}")
        t = None if temperature_c is None or temperature_c != temperature_c else float(temperature_c)
        rec = CalibrationRecord(self._new_id(), kind, time.time(), t, json.loads(_json(inputs)),
                                json.loads(_json(fitted)), json.loads(_json(residuals)))
        with self._lock:
            self._conn.execute(
                "INSERT INTO geometry_calibrations (id, kind, created, temperature_c, inputs, fitted, residuals) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)",
                (rec.id, kind, rec.created, t, json.dumps(rec.inputs), json.dumps(rec.fitted), json.dumps(rec.residuals)))
        return rec

    def import_record(self, rec: dict[str, Any]) -> CalibrationRecord:
        """Put a record made elsewhere (``CalibrationRecord.to_dict()``: a cached factory calibration) into
        this store under its own id and time; a record already there is left as it is."""
        r = CalibrationRecord(**{k: rec[k] for k in CalibrationRecord.__dataclass_fields__})
        if r.kind not in GEOMETRY_KINDS:
            raise ValueError(f"calibration kind {r.kind!r} is not one of {GEOMETRY_KINDS}")
        with self._lock:
            self._conn.execute(
                "INSERT OR IGNORE INTO geometry_calibrations (id, kind, created, temperature_c, inputs, fitted, residuals) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)", (r.id, r.kind, float(r.created), r.temperature_c, _json(r.inputs),
                                                 _json(r.fitted), _json(r.residuals)))
        return r

    @staticmethod
    def _from_row(row: sqlite3.Row) -> CalibrationRecord:
        return CalibrationRecord(id=row["id"], kind=row["kind"], created=row["created"],
                                 temperature_c=row["temperature_c"], inputs=json.loads(row["inputs"]),
                                 fitted=json.loads(row["fitted"]), residuals=json.loads(row["residuals"]))

    def latest(self, kind: str) -> CalibrationRecord | None:
        with self._lock:
            row = self._conn.execute("SELECT * FROM geometry_calibrations WHERE kind = ? "
                                     "ORDER BY created DESC, id DESC LIMIT 1", (kind,)).fetchone()
        return None if row is None else self._from_row(row)

    def recent(self, kind: str | None = None, limit: int = 20) -> list[CalibrationRecord]:
        q, args = "SELECT * FROM geometry_calibrations", []
        if kind is not None:
            q += " WHERE kind = ?"
            args.append(kind)
        with self._lock:
            rows = self._conn.execute(q + " ORDER BY created DESC, id DESC LIMIT ?", [*args, int(limit)]).fetchall()
        return [self._from_row(r) for r in rows]

    def get(self, cal_id: str) -> CalibrationRecord | None:
        with self._lock:
            row = self._conn.execute("SELECT * FROM geometry_calibrations WHERE id = ?", (cal_id,)).fetchone()
        return None if row is None else self._from_row(row)

    # -- pending plate measurements of the next range fit ------------------------------------------
    def add_range_measurement(self, data: dict[str, Any]) -> dict[str, Any]:
        mid, created = self._new_id(), time.time()
        with self._lock:
            self._conn.execute("INSERT INTO range_measurements (id, created, data) VALUES (?, ?, ?)",
                               (mid, created, _json(data)))
        return {"id": mid, "created": created, **json.loads(_json(data))}

    def range_measurements(self) -> list[dict[str, Any]]:
        """The pending plate measurements, oldest first, each ``{"id", "created", **measurement}``."""
        with self._lock:
            rows = self._conn.execute("SELECT * FROM range_measurements ORDER BY created, id").fetchall()
        return [{"id": r["id"], "created": r["created"], **json.loads(r["data"])} for r in rows]

    def remove_range_measurements(self, ids: list[str] | None = None) -> int:
        """Forget the pending measurements ``ids`` (all when None); answers how many went."""
        with self._lock:
            if ids is None:
                return self._conn.execute("DELETE FROM range_measurements").rowcount
            marks = ", ".join("?" for _ in ids) or "NULL"
            return self._conn.execute(f"DELETE FROM range_measurements WHERE id IN ({marks})", ids).rowcount
