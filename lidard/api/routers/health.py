"""GET /health: is the daemon up and is its worker alive."""

from fastapi import APIRouter

from ...jobs import software_version
from ..deps import InstrumentDep, WorkerDep
from ..schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
def health(worker: WorkerDep, instrument: InstrumentDep) -> Health:
    return Health(status="ok" if worker.running else "degraded", version=software_version(),
                  simulated=bool(instrument.simulated), worker_running=worker.running,
                  queue_length=worker.queue_length(), running_scan=worker.current_scan_id())
