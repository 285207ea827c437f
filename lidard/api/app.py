"""FastAPI application factory of the lidard daemon.

``create_app(cfg, instrument=None, data_dir=None)`` builds an app whose lifespan opens the store,
builds the instrument if none was given (``lidard.instrument.open_instrument``, imported lazily),
starts the scan worker and, on shutdown, stops the worker and closes the instrument. Nothing is
created at import time. Routers know nothing of hardware; they talk to the worker and the store.
See docs/api.md for the endpoints and the queue policy.
"""

from __future__ import annotations

import contextlib
import hmac
import logging
from pathlib import Path

from fastapi import Depends, FastAPI, HTTPException, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from ..config import Config
from ..errors import LidardError
from ..instrument_api import Instrument
from ..jobs import ScanWorker, software_version
from ..store import Store
from .routers import calibration, devices, health, scans, sim

log = logging.getLogger(__name__)


def create_app(cfg: Config, instrument: Instrument | None = None, data_dir: str | Path | None = None,
               *, token: str | None = None, max_queue: int = 16, progress_interval_s: float = 0.25,
               close_instrument: bool = True) -> FastAPI:
    """Build the daemon's app. ``token``: when set, every request needs ``Authorization: Bearer``."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        inst = instrument
        if inst is None:
            from ..instrument import open_instrument  # the composition root; heavy, so lazily
            inst = open_instrument(cfg)
        store = Store(data_dir if data_dir is not None else cfg.daemon.data_dir)
        if store.recovered:
            log.warning("%d scan(s) from a previous run marked interrupted", store.recovered)
        optics = cfg.optics()
        profile = cfg.load_profile()
        meta = {"profile": profile.name, "lens": cfg.lens or profile.default_lens, "laser": cfg.laser,
                "chirp": cfg.chirp.model_dump(), "adc": cfg.adc.model_dump(),
                "detector": cfg.detector.model_dump(), "config": cfg.source}
        worker = ScanWorker(inst, store, laser=cfg.laser, max_queue=max_queue,
                            progress_interval_s=progress_interval_s, meta=meta,
                            optics=optics)
        app.state.config, app.state.instrument, app.state.store = cfg, inst, store
        app.state.worker, app.state.optics = worker, optics
        worker.start()
        try:
            yield
        finally:
            worker.stop()
            if close_instrument:
                try:
                    inst.close()
                except Exception:
                    log.exception("closing the instrument failed")
            store.close()

    async def check_token(request: Request) -> None:
        if token is None:
            return
        got = request.headers.get("authorization", "")
        if not hmac.compare_digest(got.encode(), f"Bearer {token}".encode()):
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing or wrong bearer token",
                                headers={"WWW-Authenticate": "Bearer"})

    app = FastAPI(title="lidard", version=software_version(), lifespan=lifespan,
                  description="Control daemon for an FMCW LiDAR with a MEMS FPSA beam scanner",
                  dependencies=[Depends(check_token)])
    for r in (health.router, devices.router, scans.router, calibration.router, sim.router):
        app.include_router(r)

    @app.exception_handler(LidardError)
    async def lidard_error(request: Request, exc: LidardError) -> JSONResponse:
        # Domain errors (config, device faults reported by the instrument) are the server's state,
        # not a crash: name them instead of answering a bare 500.
        return JSONResponse({"detail": f"{type(exc).__name__}: {exc}"}, status_code=503)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
                  for e in exc.errors()]
        return JSONResponse({"detail": errors}, status_code=422)

    return app
