"""benchmarks/load.py at a small count against the fake instrument: no errors, every answer 200.

The scan is held part-way (FakeInstrument ``hold_after``) so the load really runs while a scan is
running; run_load cancels it afterwards. No timing is asserted (figures are for the benchmark).
"""

from benchmarks.load import run_load
from lidard.config import load_config
from tests.helpers.fakes import FakeInstrument


def test_small_load_has_no_errors_while_a_scan_runs():
    inst = FakeInstrument(hold_after=3)
    res = run_load(clients=10, requests_per_client=5, seed=3, instrument=inst, cfg=load_config(),
                   scan={"pattern": "roi", "rows": [0, 2], "cols": [0, 8]}, timeout_s=30.0)
    assert res["clients"] == 10 and res["requests"] == 50
    assert res["errors"] == 0 and res["statuses"] == {"200": 50}, res["first_failures"]
    assert res["scan_state_at_start"] in ("queued", "running") and res["scan_state"] == "running"
    assert res["scan_final_state"] == "cancelled"
    assert 0 < res["p50_ms"] <= res["p99_ms"] <= res["p999_ms"] <= res["max_ms"]
    assert inst.reached.is_set() and not inst.closed  # run_load does not close an instrument it was given


def test_same_seed_same_request_mix_and_bad_arguments():
    import pytest
    kw = dict(instrument=FakeInstrument(), cfg=load_config(), scan={"pattern": "roi", "rows": [0, 1], "cols": [0, 2]},
              finish="wait", timeout_s=30.0)
    a = run_load(clients=4, requests_per_client=6, seed=7, **kw)
    b = run_load(clients=4, requests_per_client=6, seed=7, **{**kw, "instrument": FakeInstrument()})
    assert a["per_path"] == b["per_path"] and sum(a["per_path"].values()) == 24
    assert set(a["per_path"]) == {"/health", "/scans", "/scans/{id}"}
    assert a["errors"] == 0 and a["scan_final_state"] == "done"
    with pytest.raises(ValueError, match="clients"):
        run_load(clients=0, **kw)
    with pytest.raises(ValueError, match="finish"):
        run_load(clients=1, requests_per_client=1, **{**kw, "finish": "later"})
