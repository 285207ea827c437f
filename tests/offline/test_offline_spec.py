"""The sweep file: expansion into configurations x targets x seeds, stable task keys, and one clear
error naming the bad key (and value) for every kind of mistake."""

from __future__ import annotations

import pytest

from lidard.offline.spec import SweepSpecError, expand_sweep, load_sweep


def test_grid_cases_targets_and_seeds_multiply(make_sweep):
    raw = make_sweep({"laser": ["dfb_default", "ideal"], "link.tx_power_w": [1e-3, 3e-3]}, seeds=3,
                     distances=(2.0, 4.0, 6.0), reflectivity=[0.1, 0.5])
    sw = expand_sweep(raw)
    assert len(sw.points) == 4
    assert len(sw.tasks) == 4 * 3 * 2 * 3
    assert sw.swept_keys == ("scan.max_range_m", "laser", "link.tx_power_w")
    assert len({t.key for t in sw.tasks}) == len(sw.tasks)
    assert len({p.config_hash for p in sw.points}) == 4
    # the overrides reach the resolved configuration the task receives
    p = next(p for p in sw.points if dict(p.params) == {"scan.max_range_m": 15.0, "laser": "ideal",
                                                          "link.tx_power_w": 3e-3})
    assert p.cfg.laser == "ideal" and p.cfg.link.tx_power_w == 3e-3 and p.laser.coherence_time_s == float("inf")
    raw["cases"] = [{"scan.averages": 1}, {"scan.averages": 4, "dsp.estimator": "jacobsen"}]
    sw2 = expand_sweep(raw)
    assert len(sw2.points) == 8
    assert {p.dsp.estimator for p in sw2.points} == {"newton", "jacobsen"}


def test_task_keys_are_stable_and_follow_the_configuration(make_sweep):
    a = expand_sweep(make_sweep({"link.tx_power_w": 1e-3}))
    b = expand_sweep(make_sweep({"link.tx_power_w": 1e-3}))
    c = expand_sweep(make_sweep({"link.tx_power_w": 2e-3}))
    assert [t.key for t in a.tasks] == [t.key for t in b.tasks]
    assert not {t.key for t in a.tasks} & {t.key for t in c.tasks}


def test_linspace_distances_and_seed_lists(make_sweep):
    raw = make_sweep()
    raw["target"]["distances_m"] = {"start": 1.0, "stop": 10.0, "num": 4}
    raw["sweep"]["seeds"] = [7, 9]
    sw = expand_sweep(raw)
    assert sorted({t.distance_m for t in sw.tasks}) == [1.0, 4.0, 7.0, 10.0]
    assert {t.seed for t in sw.tasks} == {7, 9}


@pytest.mark.parametrize("grid, pattern", [
    ({"link.tx_powr_w": 1e-3}, r"grid\.link\.tx_powr_w: unknown key"),
    ({"devices.fpsa.url": "x"}, r"grid\.devices\.fpsa\.url: not a key"),
    ({"adc.iq": True}, r"grid\.adc\.iq: cannot be swept: .*I/Q"),
    ({"monitor.quadrature": True}, r"grid\.monitor\.quadrature: cannot be swept: .*quadrature"),
    ({"link.reflectivity": 0.3}, r"grid\.link\.reflectivity: cannot be swept: .*\[target\] reflectivity"),
    ({"link.tx_power_w": [1e-3, -1.0]}, r"grid\.link\.tx_power_w: .*greater than 0 \(got -1\.0"),
    ({"laser": "dfb_nope"}, r"grid: laser: 'dfb_nope' is not a preset; allowed: .*dfb_default"),
    ({"lens": "fisheye"}, r"grid: lens: 'fisheye' is not a lens of profile fpsa128"),
    ({"dsp.estimator": "magic"}, r"grid\.dsp\.estimator: .*'argmax'.*\(got 'magic'"),
    ({"scan.window": "kaiser"}, r"grid\.scan\.window: .*\(got 'kaiser'"),
    ({"laser": []}, r"grid\.laser: an empty list sweeps nothing"),
])
def test_bad_grid_entries_name_the_key(make_sweep, grid, pattern):
    with pytest.raises(SweepSpecError, match=pattern):
        expand_sweep(make_sweep(grid))


def test_bad_file_structure_names_the_key(make_sweep, tmp_path):
    raw = make_sweep()
    raw["sweep"]["trails_per_task"] = 3
    with pytest.raises(SweepSpecError, match=r"sweep\.trails_per_task: unknown key"):
        expand_sweep(raw)
    raw = make_sweep()
    raw["target"]["distances_m"] = [3.0, -1.0]
    with pytest.raises(SweepSpecError, match=r"target\.distances_m"):
        expand_sweep(raw)
    raw = make_sweep()
    raw["sweep"]["base_config"] = "nowhere.toml"
    with pytest.raises(SweepSpecError, match=r"sweep\.base_config: 'nowhere\.toml' not found"):
        expand_sweep(raw)
    raw = make_sweep(seeds=[1, 1])
    with pytest.raises(SweepSpecError, match=r"listed twice"):
        expand_sweep(raw)
    bad = tmp_path / "s.toml"
    bad.write_text("[sweep\n")
    with pytest.raises(SweepSpecError, match=r"s\.toml: cannot read as TOML"):
        load_sweep(bad)


def test_the_packaged_benchmark_sweep_has_the_promised_size():
    from pathlib import Path
    sw = load_sweep(Path(__file__).resolve().parents[2] / "config" / "sweeps" / "lasers_powers.toml")
    lasers = {dict(p.params)["laser"] for p in sw.points}
    powers = {dict(p.params)["link.tx_power_w"] for p in sw.points}
    assert len(lasers) == 3 and len(powers) == 3
    assert len({t.distance_m for t in sw.tasks}) == 20 and len({t.seed for t in sw.tasks}) == 20
    assert len(sw.tasks) == 3 * 3 * 20 * 20
