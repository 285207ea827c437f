"""The laser/HV controller's latched safety faults: ``POST /controller/acknowledge``.

A latched fault (the interlock opened, an HV supply trip; docs/protocols/controller.md) keeps the laser
and the FPSA's HV (dissertation §4.3.3) off until a person resets it, as laser safety expects. The
reset clears the latches only when their causes are gone: 409 names what is still open. It is a
mutating request, so the control lock applies (lidard.api.control): the answer names the lease
holder who acknowledged ("anonymous" when no lease is held), and the daemon logs who and when.
"""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..deps import InstrumentDep
from ..schemas import _Out

router = APIRouter(prefix="/controller", tags=["controller"])

ACK_COMMAND = "lidarctl faults ack"


class FaultsAcknowledged(_Out):
    cleared: list[str]
    by: str
    at: float


def acknowledged_by(request: Request) -> str:
    """The lease holder's name: the app's guard has already answered 423 to a mutating request that
    does not carry the held lease, so a request that gets here while a lease is held carries it."""
    lease = request.app.state.control_lock.holder()
    return lease.holder if lease is not None else "anonymous"


@router.post("/acknowledge", response_model=FaultsAcknowledged,
             responses={409: {"description": "a latched fault's cause is still present (named)"}})
def acknowledge(request: Request, instrument: InstrumentDep) -> FaultsAcknowledged:
    """Clear the controller's latched faults whose cause is gone (interlock closed, no HV fault)."""
    # FaultsStillOpen (a cause is still present): 409
    return FaultsAcknowledged(**instrument.acknowledge_faults(acknowledged_by(request)))


def latched_refusal(instrument) -> str | None:
    """Why no scan can run now (a fault latched in the controller), with the command to run; None
    when nothing is latched or the controller cannot be read (the scan then reports the real error)."""
    try:
        state = instrument.controller_faults()
    except Exception:
        return None
    if not state["latched"]:
        return None
    return (f"controller faults latched: {', '.join(state['latched'])}; laser and HV stay off until they "
            f"are acknowledged: remove the cause, then run `{ACK_COMMAND}` (POST /controller/acknowledge)")
