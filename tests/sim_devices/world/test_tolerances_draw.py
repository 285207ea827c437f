"""The bench's hidden truths (sim_devices.world.tolerances): seeded draws within the bounds of
``[sim.tolerances]``, the bounds themselves with draw = false, nominal when switched off."""

import math

import pytest

from lidard.config import Tolerances
from lidard.physics.optics import Pointing
from sim_devices.world.tolerances import BenchTruth, draw_truth

NOM = 200e-9
POINTING_FIELDS = ("focal_rel", "decentre_px", "rotation_deg", "k1")


def _within(t: BenchTruth, tol: Tolerances) -> None:
    assert abs(t.mzi_delay_s / NOM - 1) <= tol.mzi_delay_rel
    assert 0.0 <= t.zero_offset_m <= tol.zero_offset_m          # a path length: never negative
    p = t.pointing
    assert abs(p.focal_scale - 1) <= tol.focal_rel
    assert all(abs(d) <= tol.decentre_px for d in p.decentre_px)
    assert abs(p.rotation_rad) <= math.radians(tol.rotation_deg)
    assert abs(p.k1) <= tol.k1
    assert abs(20 * math.log10(t.iq_gain)) <= tol.hybrid_gain_db + 1e-12
    assert abs(t.iq_phase_rad) <= math.radians(tol.hybrid_phase_deg)


def test_draws_are_reproducible_seeded_and_within_bounds():
    tol = Tolerances()
    draws = [draw_truth(tol, nominal_mzi_delay_s=NOM, seed=s) for s in range(40)]
    for t in draws:
        _within(t, tol)
    assert draw_truth(tol, nominal_mzi_delay_s=NOM, seed=7) == draws[7]     # same seed, same bench
    assert len({t.mzi_delay_s for t in draws}) == 40                       # other seeds, other benches
    # the draws spread over their range (not stuck at a bound or at zero): both signs of eps show up
    eps = [t.mzi_delay_rel for t in draws]
    assert min(eps) < -0.005 and max(eps) > 0.005
    assert max(t.zero_offset_m for t in draws) > 0.03
    # tolerances.seed wins over the bench's seed
    a = draw_truth(Tolerances(seed=5), nominal_mzi_delay_s=NOM, seed=1)
    assert a == draw_truth(Tolerances(seed=5), nominal_mzi_delay_s=NOM, seed=99) == draws[5]


def test_draw_false_takes_each_bound():
    tol = Tolerances(draw=False, mzi_delay_rel=0.02, zero_offset_m=0.03, focal_rel=0.01,
                     decentre_px=0.5, rotation_deg=0.4, k1=0.15)
    t = draw_truth(tol, nominal_mzi_delay_s=NOM, seed=3)
    assert t.mzi_delay_s == pytest.approx(NOM * 1.02, rel=1e-15)
    assert t.zero_offset_m == 0.03
    assert t.pointing == Pointing(1.01, (0.5, 0.5), math.radians(0.4), 0.15)
    hyb = draw_truth(Tolerances(draw=False, hybrid_gain_db=0.6, hybrid_phase_deg=4.0), nominal_mzi_delay_s=NOM, seed=3)
    assert hyb.iq_gain == pytest.approx(10 ** (0.6 / 20), rel=1e-15)
    assert hyb.iq_phase_rad == pytest.approx(math.radians(4.0), rel=1e-15)


def test_hybrid_imbalance_is_drawn_on_its_own_streams():
    draws = [draw_truth(Tolerances(), nominal_mzi_delay_s=NOM, seed=s) for s in range(40)]
    g_db = [20 * math.log10(t.iq_gain) for t in draws]
    ph = [t.iq_phase_rad for t in draws]
    assert min(g_db) < -0.25 and max(g_db) > 0.25 and min(ph) < -0.04 and max(ph) > 0.04
    # switching the hybrid off leaves the other draws as they were, and gives an ideal hybrid
    off = draw_truth(Tolerances(hybrid_gain_db=0.0, hybrid_phase_deg=0.0), nominal_mzi_delay_s=NOM, seed=2)
    on = draw_truth(Tolerances(), nominal_mzi_delay_s=NOM, seed=2)
    assert (off.iq_gain, off.iq_phase_rad) == (1.0, 0.0)
    assert (off.mzi_delay_s, off.zero_offset_m, off.pointing) == (on.mzi_delay_s, on.zero_offset_m, on.pointing)


def test_disabled_is_the_nominal_bench():
    t = draw_truth(Tolerances(enabled=False), nominal_mzi_delay_s=NOM, seed=1)
    assert t == BenchTruth.nominal(NOM)
    assert t.mzi_delay_s == NOM and t.zero_offset_m == 0.0 and t.pointing.nominal


@pytest.mark.parametrize("name", ["mzi_delay_rel", "zero_offset_m", *POINTING_FIELDS])
def test_each_bound_zero_switches_only_that_one_off(name):
    on = draw_truth(Tolerances(), nominal_mzi_delay_s=NOM, seed=2)
    off = draw_truth(Tolerances(**{name: 0.0}), nominal_mzi_delay_s=NOM, seed=2)
    nominal = {"mzi_delay_rel": off.mzi_delay_s == NOM, "zero_offset_m": off.zero_offset_m == 0.0,
               "focal_rel": off.pointing.focal_scale == 1.0,
               "decentre_px": tuple(off.pointing.decentre_px) == (0.0, 0.0),
               "rotation_deg": off.pointing.rotation_rad == 0.0, "k1": off.pointing.k1 == 0.0}
    assert nominal[name]
    # every other tolerance keeps its draw (one random stream each)
    others = {"mzi_delay_rel": on.mzi_delay_s == off.mzi_delay_s,
              "zero_offset_m": on.zero_offset_m == off.zero_offset_m,
              "focal_rel": on.pointing.focal_scale == off.pointing.focal_scale,
              "decentre_px": on.pointing.decentre_px == off.pointing.decentre_px,
              "rotation_deg": on.pointing.rotation_rad == off.pointing.rotation_rad,
              "k1": on.pointing.k1 == off.pointing.k1}
    assert all(v for k, v in others.items() if k != name)
    assert not others[name]


def test_round_trip_through_a_dict():
    t = draw_truth(Tolerances(), nominal_mzi_delay_s=NOM, seed=4)
    assert BenchTruth.from_dict(t.as_dict()) == t
    with pytest.raises(ValueError, match="zero_offset_m"):
        BenchTruth(NOM, -0.01)
