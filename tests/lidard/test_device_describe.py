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
