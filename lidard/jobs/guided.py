"""The guided calibration: range plates, the range fit, then pointing, as one procedure with progress.

What a lab does in order (the steps of :mod:`.calibrations`, dissertation §2.1.1 and §4.1.1):

1. pending plates of an earlier, aborted run are listed; they must be kept (they join this fit) or
   dropped (``pending="keep" | "drop"``), never entered silently;
2. a flat plate at each known distance along the optical axis (``plates_m``), each measured on the centre
   pixels (:func:`lidard.instrument.calibration.procedures.measure_plate`);
3. the range fit (effective monitor delay, zero offset), stored and applied: the chirp is re-linearized
   against the fitted delay;
4. targets of known geometry (``geometry``, the geometry file's structure) scanned with the calibrated
   ranges and the pointing model fitted, stored and applied.

Who moves the fixtures is the caller's ``place``: on a simulated bench the procedure places them itself
through the instrument (the bench's scene, as a lab places them by hand: the daemon learns the bench's
truths only through the measurements), and puts the scene it found back at the end; on real hardware
``lidarctl calibrate`` asks the operator for each position over the REST steps instead.

:func:`run_guided` runs ON the worker thread (from a queued task, or before a scan: the factory
calibration of a simulated bench, :meth:`lidard.jobs.worker.ScanWorker.factory_calibration`).

The factory plan is small on purpose (it runs unattended before a first scan): three plates, the
fewest that leave the range fit a degree of freedom for its chi-square test, at 0.8-1.4 m (the
distances of the range fit's docs/tolerances.md figures); five spheres spread over the field for the
pointing model's five parameters.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Literal
from collections.abc import Callable

log = logging.getLogger("lidard.jobs")

FACTORY_PLATES_M: tuple[float, ...] = (0.8, 1.1, 1.4)
#: five 35 mm spheres at z = 1 m: the centre and four towards the corners of the central field
FACTORY_GEOMETRY: dict[str, Any] = {"sphere": [{"centre": [x, y, 1.0], "radius": 0.035} for x, y in
                                               [(0.0, 0.0), (0.09, 0.09), (-0.09, 0.09), (0.09, -0.09), (-0.09, -0.08)]]}

Pending = Literal["keep", "drop", "refuse"]
Progress = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class GuidedPlan:
    plates_m: tuple[float, ...] = FACTORY_PLATES_M
    geometry: dict[str, Any] = field(default_factory=lambda: dict(FACTORY_GEOMETRY))


def bench_scene(cfg, worker) -> dict[str, Any]:
    """The scene a daemon's simulated bench shows: the last one placed over REST (``worker.sim_scene``),
    else the configuration's ``sim.scene`` file."""
    import tomllib
    if getattr(worker, "sim_scene", None) is not None:
        return worker.sim_scene
    with open(cfg.resolve_path(cfg.sim.scene), "rb") as f:
        return tomllib.load(f)


def pending_refusal(pending: list[dict[str, Any]]) -> str:
    listing = ", ".join(f"{m['id']} ({m['known_m']:g} m)" for m in pending)
    return (f"{len(pending)} plate(s) of an earlier calibration run are pending: {listing}; keep them in this fit "
            "or drop them (lidarctl calibrate --keep-pending / --drop-pending; REST: \"pending\": \"keep\" | \"drop\")")


def resolve_pending(store, pending: Pending) -> list[dict[str, Any]]:
    """Apply the pending-plates policy; answers the plates kept."""
    from ..instrument.calibration.range import CalibrationRefused
    waiting = store.geometry.range_measurements()
    if not waiting:
        return []
    if pending == "drop":
        store.geometry.remove_range_measurements([m["id"] for m in waiting])
        return []
    if pending == "keep":
        return waiting
    raise CalibrationRefused("calibration: " + pending_refusal(waiting))


def run_guided(worker, plan: GuidedPlan, nominal_delay_s: float, *, pending: Pending = "refuse",
               progress: Progress | None = None) -> dict[str, Any]:
    """The whole procedure on the worker thread, placing the fixtures on the simulated bench through the
    instrument (:class:`NotSimulated` on real hardware); answers ``{"range": record, "pointing": record,
    "plates": [...], "kept_pending": [...], "wall_s"}``."""
    from ..instrument.calibration.pointing import parse_geometry, spheres_scene
    from ..instrument.calibration.range import plate_scene
    from . import calibrations as cal

    say = progress or (lambda _e: None)
    inst, store = worker.instrument, worker.store
    surfaces = parse_geometry(plan.geometry, source="<calibration plan>")
    t0 = time.perf_counter()
    kept = resolve_pending(store, pending)
    n = len(plan.plates_m)
    steps = n + 2
    say({"step": "start", "plates_m": list(plan.plates_m), "kept_pending": [m["id"] for m in kept], "steps": steps})
    plates = []
    for i, d in enumerate(plan.plates_m):
        say({"step": "plate", "index": i + 1, "of": n, "known_m": float(d), "done": i, "steps": steps})
        inst.set_scene(plate_scene(float(d)))
        m = cal.plate_now(worker, float(d))
        plates.append(m)
        say({"step": "plate_done", "index": i + 1, "of": n, "known_m": float(d), "raw_range_m": m["raw_range_m"],
             "sem_m": m["sem_m"], "n": m["n"], "done": i + 1, "steps": steps})
    rng = cal.fit_range(store, nominal_delay_s, worker.setup_of("range"))
    say({"step": "range_fit", "id": rng.id, "delay_s": rng.fitted["delay_s"],
         "zero_offset_m": rng.fitted["zero_offset_m"], "done": n + 1, "steps": steps})
    inst.set_scene(spheres_scene(surfaces))
    pnt = cal.pointing_now(worker, surfaces)
    say({"step": "pointing", "id": pnt.id, "rms_mm": pnt.residuals.get("rms_mm"), "done": steps, "steps": steps})
    return {"range": rng.to_dict(), "pointing": pnt.to_dict(), "plates": plates, "kept_pending": kept,
            "wall_s": time.perf_counter() - t0}


@dataclass
class FactoryCalibration:
    """A simulated bench's factory calibration before its first scan without a calibration of its set-up.

    ``scene()`` answers the scene (the scene file's structure) to put back on the bench once the fixtures
    are done, None to leave them. Tried once per worker: a refused run is reported, not retried at every
    scan (the scans then say why they are uncalibrated)."""

    nominal_delay_s: float
    scene: Callable[[], dict[str, Any] | None]
    plan: GuidedPlan = field(default_factory=GuidedPlan)
    announce: Callable[[str], None] | None = None
    tried: bool = False
    result: dict[str, Any] | None = None
    refused: str | None = None

    def run_if_needed(self, worker, progress: Progress | None = None) -> dict[str, Any] | None:
        """On the worker thread: run the plan when the store has no range or pointing record of this
        set-up; answers its result (None when nothing ran or it was refused)."""
        from ..instrument.calibration.range import CalibrationRefused
        if self.tried:
            return None
        applied = worker.apply_geometry()
        missing = [k for k, have in (("range", applied.range_id), ("pointing", applied.pointing_id)) if have is None]
        if not missing:
            return None
        self.tried = True
        why = f"no {' or '.join(missing)} calibration of this set-up"
        msg = (f"{why}: running the simulated bench's factory calibration (plates at "
               f"{', '.join(f'{d:g}' for d in self.plan.plates_m)} m, then {len(self.plan.geometry.get('sphere', []))} "
               "spheres; placed through the bench, measured through the instruments)")
        log.info(msg)
        if self.announce is not None:
            self.announce(msg)
        try:
            self.result = run_guided(worker, self.plan, self.nominal_delay_s, pending="refuse", progress=progress)
        except CalibrationRefused as exc:
            self.refused = str(exc)
            log.warning("factory calibration refused: %s", exc)
            return None
        finally:
            scene = self.scene()
            if scene is not None:
                worker.instrument.set_scene(scene)
        return self.result
