"""Typed dependency aliases: routers receive the daemon's objects from ``app.state``, never globals."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from ..config import Config
from ..instrument.protocol import Instrument
from ..jobs import ScanWorker
from ..physics.optics import FpsaOptics
from ..store import Store


def get_config(request: Request) -> Config:
    return request.app.state.config


def get_instrument(request: Request) -> Instrument:
    return request.app.state.instrument


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_worker(request: Request) -> ScanWorker:
    return request.app.state.worker


def get_optics(request: Request) -> FpsaOptics:
    return request.app.state.optics


ConfigDep = Annotated[Config, Depends(get_config)]
InstrumentDep = Annotated[Instrument, Depends(get_instrument)]
StoreDep = Annotated[Store, Depends(get_store)]
WorkerDep = Annotated[ScanWorker, Depends(get_worker)]
OpticsDep = Annotated[FpsaOptics, Depends(get_optics)]
