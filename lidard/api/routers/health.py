"""GET /health: is the daemon up, is its worker alive, and is a controller fault latched."""

from fastapi import APIRouter

from ...jobs import software_version
from ..deps import InstrumentDep, WorkerDep
from ..schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
def health(worker: WorkerDep, instrument: InstrumentDep) -> Health:
    try:
        ctl = instrument.controller_faults()
        latched, interlock = list(ctl["latched"]), bool(ctl["interlock_closed"])
    except Exception:            # unreadable controller: unknown, GET /devices says why
        latched, interlock = None, None
    return Health(latched_faults=latched, interlock_closed=interlock,status="ok" if worker.running else "degraded", version=software_version(),
                  simulated=bool(instrument.simulated), worker_running=worker.running,
                  queue_length=worker.queue_length(), running_scan=worker.current_scan_id(),
                  linearization=worker.last_linearization)
