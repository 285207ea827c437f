"""GET /devices shows device replies as readable lines, never Python reprs (issue 11)."""

from __future__ import annotations

import dataclasses
import enum
from typing import NamedTuple

from lidard.instrument.devices import describe


class State(enum.Enum):
    IDLE = 0
    DONE = 3


class Fault(enum.Flag):
    NONE = 0
    OVERTEMP = 1
    HV = 2


@dataclasses.dataclass(frozen=True)
class Status:
    state: State
    faults: Fault
    hv_v: float
    rows: tuple


class Ident(NamedTuple):
    model: str
    firmware: tuple


def test_dataclass_reply_reads_as_key_value_pairs():
    s = describe(Status(State.DONE, Fault.OVERTEMP | Fault.HV, 41.23456, tuple(range(96))))
    assert s == "state=DONE, faults=OVERTEMP+HV, hv_v=41.23, rows=96 values"
    assert "<" not in s and "Status(" not in s


def test_named_tuple_empty_flags_and_sets():
    assert describe(Ident("LHV-1550", (1, 0))) == "model=LHV-1550, firmware=[1, 0]"
    assert describe(Status(State.IDLE, Fault.NONE, 0.0, ())) == "state=IDLE, faults=none, hv_v=0, rows=none"
    assert describe(frozenset({"B", "A"})) == "A+B"
    assert describe([]) == "none"


# -- GET /devices carries the same replies as data (``status``/``identity_fields``), which lidarctl reads
def test_as_data_gives_json_values_not_reprs():
    import json

    from lidard.instrument.devices import ErrorQueue, as_data
    data = as_data(Status(State.DONE, Fault.OVERTEMP | Fault.HV, 41.25, tuple(range(3))))
    assert data == {"state": "DONE", "faults": ["OVERTEMP", "HV"], "hv_v": 41.25, "rows": [0, 1, 2]}
    assert as_data(Ident("LHV", (1, 0))) == {"model": "LHV", "firmware": [1, 0]}
    assert as_data(Status(State.IDLE, Fault.NONE, 0.0, ()))["faults"] == []
    assert json.loads(json.dumps(data)) == data
    # the AWG has no status word: its error queue, said as "ready" when empty (not "none")
    assert as_data(ErrorQueue(())) == {"error_queue": []}
    assert describe(ErrorQueue(())) == "ready (error queue empty)"
    assert describe(ErrorQueue(((-222, "Data out of range"),))) == "error -222: Data out of range"


def test_registry_entries_validate_as_the_typed_api_model():
    from lidard.api.schemas import DeviceStatus
    from lidard.instrument.devices import DeviceRegistry

    class Dev:
        def identify(self):
            return Ident("X-1", (2, 1))

        def status(self):
            return Status(State.IDLE, Fault.HV, 3.5, (1, 2))

        def errors(self):
            return [(-113, "Undefined header")]

    class Idn(Dev):
        def identify(self):
            return "acme,ADC,0001,1.0"

    reg = DeviceRegistry(Dev(), Dev(), Idn(), Dev())
    reg.identify_all()
    entries = [DeviceStatus.model_validate(e) for e in reg.check_all()]
    fpsa, awg, dig, _ = entries
    assert fpsa.status == {"state": "IDLE", "faults": ["HV"], "hv_v": 3.5, "rows": [1, 2]} and fpsa.faults == ["HV"]
    assert fpsa.identity_fields == {"model": "X-1", "firmware": [2, 1]} and not fpsa.busy
    assert awg.status == {"error_queue": [{"code": -113, "text": "Undefined header"}]}
    assert dig.identity_fields == {"idn": "acme,ADC,0001,1.0"}
    busy = [DeviceStatus.model_validate(e) for e in reg.busy_listing()]
    assert all(b.busy and b.status is None for b in busy)


def test_lidarctl_reads_the_status_data():
    from lidard.cli.devices import device_rows
    rows = device_rows([{"name": "fpsa", "connected": True, "busy": True, "faults": ["HV"],
                         "identity_fields": {"model": "X-1", "firmware": [2, 1]},
                         "state": "ignored when status is there",
                         "status": {"state": "IDLE", "faults": ["HV"], "rows": list(range(96))}},
                        {"name": "awg", "connected": True, "status": {"error_queue": []}}])
    assert rows[0] == ["fpsa", "connected (busy: last check)", "model=X-1, firmware=2.1",
                       "idle, rows=96 values, 0..95", "HV"]
    assert rows[1][3] == "ready"
