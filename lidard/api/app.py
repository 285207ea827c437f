"""FastAPI application factory of the lidard daemon.

``create_app(cfg, instrument=None, data_dir=None)`` builds an app whose lifespan opens the store
(or takes an open one: ``store=``; the store holds the data directory's lock), builds the instrument if none was given (``lidard.instrument.open_instrument``, imported lazily),
starts the scan worker and, on shutdown, stops the worker and closes the instrument. Nothing is
created at import time. Routers know nothing of hardware; they talk to the worker and the store.
See docs/api.md for the endpoints and the queue policy.

Length: ``create_app`` is about 70 lines with its docstring because the lifespan stays a
closure over the factory's arguments (the store, instrument and worker it builds live exactly as
long as the app); the scan metadata and the error handlers are separate functions.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from fastapi import Depends, FastAPI, Request
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from ..config import Config
from ..instrument.protocol import Instrument
from ..instrument.calibration.setup import instrument_setup
from ..jobs import ScanWorker, software_version
from ..outputs import scene_identity
from ..store import Store
from . import control, problems
from .control import BodySizeLimit, ControlLock, LockHeld
from ..live.points import LivePoints
from .routers import calibration, controller, devices, geometry, health, raw, scans, selftest, sim, streams, viewer

log = logging.getLogger(__name__)


def _factory(cfg: Config, worker: ScanWorker):
    """The factory calibration of the daemon's bench; it puts back the scene the bench showed: the last
    one placed (PUT /sim/scene keeps it as ``worker.sim_scene``), else the configuration's."""
    from ..jobs.guided import FactoryCalibration, bench_scene
    return FactoryCalibration(nominal_delay_s=cfg.monitor.delay_s, scene=lambda: bench_scene(cfg, worker))


@dataclass(frozen=True)
class ApiAccess:
    """Who may change what, and how much a request may carry.

    ``token``: when set, mutating requests (POST/PUT/PATCH/DELETE) need ``Authorization: Bearer``;
    reads stay open. ``lease_ttl_s`` (default ``cfg.daemon.lease_ttl_s``)/``clock``: the control lock
    (lidard.api.control). ``max_body_bytes``: request body limit (413 above it), default
    ``cfg.daemon.max_body_bytes``.
    """

    token: str | None = None
    lease_ttl_s: float | None = None
    clock: Callable[[], float] = time.monotonic
    max_body_bytes: int | None = None


@dataclass(frozen=True)
class WorkerOptions:
    """How the scan worker runs: its queue bound, how often it reports progress, and
    ``factory_calibration``: run a simulated bench's factory calibration before the first scan when no
    range/pointing record of its set-up is stored (lidard.jobs.guided); default (None): when the app
    opens a simulated bench itself and ``sim.factory_calibration`` is on."""

    max_queue: int = 16
    progress_interval_s: float = 0.25
    factory_calibration: bool | None = None


_OPEN_ACCESS = ApiAccess()        # no token; the configuration's lease and body limit
_DEFAULT_WORKER = WorkerOptions()


def create_app(cfg: Config, instrument: Instrument | None = None, data_dir: str | Path | None = None,
               *, store: Store | None = None, close_instrument: bool = True, access: ApiAccess = _OPEN_ACCESS,
               worker_options: WorkerOptions = _DEFAULT_WORKER) -> FastAPI:
    """Build the daemon's app.

    ``access``: the token, control lease and request body limit (:class:`ApiAccess`);
    ``worker_options``: the scan worker's queue, progress interval and factory calibration
    (:class:`WorkerOptions`); ``close_instrument``: close the instrument when the app stops.
    """
    token, lease_ttl_s, clock, max_body_bytes = access.token, access.lease_ttl_s, access.clock, access.max_body_bytes
    max_queue, progress_interval_s = worker_options.max_queue, worker_options.progress_interval_s
    factory_calibration = worker_options.factory_calibration

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        # The store first: it takes the data directory's lock, so a second daemon on the same
        # directory is refused before it starts a bench or touches the hardware.
        st = store if store is not None else Store(data_dir if data_dir is not None else cfg.daemon.data_dir)
        inst = instrument
        if inst is None:
            from ..instrument import open_instrument  # the composition root; heavy, so lazily
            try:
                inst = open_instrument(cfg)
            except BaseException:
                st.close()
                raise
        if st.recovered:
            log.warning("%d scan(s) from a previous run marked interrupted", st.recovered)
        optics = cfg.resolved.optics
        worker = ScanWorker(inst, st, laser=cfg.laser, max_queue=max_queue,
                            progress_interval_s=progress_interval_s, meta=_scan_meta(cfg, inst),
                            optics=optics, recalibrate_delta_c=cfg.scan.recalibrate_delta_c,
                            setup=instrument_setup(cfg, inst))
        factory = (instrument is None and cfg.sim.factory_calibration) if factory_calibration is None \
            else factory_calibration
        if factory and cfg.sim.enabled and inst.simulated:
            worker.factory = _factory(cfg, worker)
        app.state.config, app.state.instrument, app.state.store = cfg, inst, st
        app.state.worker, app.state.optics = worker, optics
        app.state.live = LivePoints()
        worker.add_point_listener(app.state.live)  # the web viewer's incremental points
        app.state.foxglove = None
        if cfg.live.foxglove:
            from ..live.foxglove_server import FoxgloveLive  # opt-in; starts a WebSocket server
            app.state.foxglove = FoxgloveLive(cfg.live.foxglove_host, cfg.live.foxglove_port, devices=inst.devices)
            worker.add_point_listener(app.state.foxglove.on_points)
            worker.add_event_listener(app.state.foxglove.on_event)
        worker.start()
        try:
            yield
        finally:
            streams.stop_all(app)   # a running stream ends after its frame in progress (frames kept)
            worker.stop()
            if app.state.foxglove is not None:
                app.state.foxglove.close()
            if close_instrument:
                try:
                    inst.close()
                except Exception:
                    log.exception("closing the instrument failed")
            st.close()

    app = FastAPI(title="lidard", version=software_version(), lifespan=lifespan,
                  description="Control daemon for an FMCW LiDAR with a MEMS FPSA beam scanner",
                  dependencies=[Depends(control.guard(token))])
    app.state.control_lock = ControlLock(ttl_s=cfg.daemon.lease_ttl_s if lease_ttl_s is None else lease_ttl_s,
                                         clock=clock)
    app.add_middleware(BodySizeLimit, max_body_bytes=int(
        max_body_bytes if max_body_bytes is not None else cfg.daemon.max_body_bytes))
    app.include_router(control.router)
    control.document_gates(app, token_set=token is not None)
    for r in (health.router, devices.router, scans.router, raw.router, calibration.router, geometry.router,
              sim.router, selftest.router, viewer.router, controller.router, streams.router):
        app.include_router(r)
    app.mount("/viewer", StaticFiles(directory=viewer.STATIC_DIR), name="viewer")
    _add_error_handlers(app)
    return app


def _scan_meta(cfg: Config, inst: Instrument) -> dict:
    """What every scan's sidecar records about the set-up it was measured with."""
    profile = cfg.resolved.profile
    meta = {"profile": profile.name, "lens": cfg.lens or profile.default_lens, "laser": cfg.laser,
            "chirp": cfg.chirp.model_dump(), "adc": cfg.adc.model_dump(),
            "detector": cfg.detector.model_dump(), "config": cfg.source}
    if inst.simulated and cfg.sim.enabled:
        # the sidecar names the world a simulated scan saw (PUT /sim/scene replaces this entry)
        meta["scene"] = scene_identity(cfg.resolve_path(cfg.sim.scene))
    return meta


def _add_error_handlers(app: FastAPI) -> None:
    # every error answer is an RFC 9457 problem (lidard.api.problems)
    problems.install(app)

    # (domain errors: their own status, lidard.errors.LidardError.http_status, in problems.install)
    @app.exception_handler(LockHeld)
    async def lock_held(request: Request, exc: LockHeld) -> JSONResponse:
        return control.locked_response(exc)
