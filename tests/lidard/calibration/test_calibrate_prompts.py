"""``lidarctl calibrate`` on real hardware asks the operator for each plate position and waits: a live
daemon whose instrument is a NON-simulated fake with a plate (ranges R_raw = s (d / d_z + z0) + noise,
tests.lidard.calibration.test_calibration_cli.PlateFake); the "operator" moves the fake's plate to the
distance each prompt names. The fit through CLI -> REST -> worker -> store must find s and z0."""

from __future__ import annotations

import re

import pytest

from tests.helpers.api import live_server, make_app
from tests.helpers.cli import run
from tests.lidard.calibration.test_calibration_cli import S_TRUE, Z0_TRUE, PlateFake


@pytest.fixture
def lab(tmp_path):
    inst = PlateFake()
    inst.simulated = False
    with live_server(make_app(tmp_path / "data", inst, progress_interval_s=0.0)) as url:
        yield url, inst


def _operator(inst, prompts: list[str], abort_at: int | None = None):
    def answer(prompt: str) -> str:
        prompts.append(prompt)
        if abort_at is not None and len(prompts) == abort_at:
            return "q"
        m = re.search(r"at z = ([\d.]+) m", prompt)
        if m:
            inst.plate_m = float(m.group(1))     # the plate is moved where the prompt says
        return ""
    return answer


def test_real_hardware_prompts_for_each_plate_and_an_aborted_run_leaves_them_pending(capsys, lab, monkeypatch, tmp_path):
    url, inst = lab
    geo = tmp_path / "targets.toml"
    geo.write_text("[[sphere]]\ncentre = [0.0, 0.0, 1.0]\nradius = 0.03\n")
    code, out, err = run(capsys, "calibrate", "--url", url)
    assert code != 0 and "--geometry" in err and "real hardware" in err          # asked before anything moves

    prompts: list[str] = []
    monkeypatch.setattr("builtins.input", _operator(inst, prompts, abort_at=2))
    code, out, err = run(capsys, "calibrate", "--url", url, "--geometry", str(geo), "--plates", "0.8", "1.5")
    assert code != 0 and "aborted" in err
    assert "at z = 0.8 m" in prompts[0] and "at z = 1.5 m" in prompts[1]
    code, out, err = run(capsys, "calibration", "range", "list", "--url", url, "--json")
    import json
    pending = json.loads(out)
    assert [m["known_m"] for m in pending] == [0.8]

    # the next run lists the pending plate and stops; kept, it joins the fit (three plates)
    code, out, err = run(capsys, "calibrate", "--url", url, "--geometry", str(geo), "--plates", "1.1", "1.5")
    assert code != 0 and pending[0]["id"] in err and "--keep-pending" in err
    prompts.clear()
    monkeypatch.setattr("builtins.input", _operator(inst, prompts, abort_at=3))   # stop at the pointing targets
    code, out, err = run(capsys, "calibrate", "--url", url, "--geometry", str(geo), "--plates", "1.1", "1.5",
                         "--keep-pending")
    assert code != 0 and "aborted" in err
    assert "pointing targets" in prompts[2] and str(geo) in prompts[2]
    assert "keeping 1 pending plate" in err and "[3/4] range calibration" in err
    code, out, err = run(capsys, "calibration", "list", "--kind", "range", "--url", url, "--json")
    rec = json.loads(out)[0]
    assert sorted(m["known_m"] for m in rec["inputs"]["measurements"]) == [0.8, 1.1, 1.5]
    # R_raw = s (R + z0): the fitted delay is nominal / s and the zero offset z0
    assert rec["fitted"]["scale"] == pytest.approx(S_TRUE, rel=2e-5)
    assert rec["fitted"]["zero_offset_m"] == pytest.approx(Z0_TRUE, abs=1e-4)
