"""benchmarks/child_scan_pd.py: the Pd model of the child-bench e2e scan (its pieces that run without a bench)."""

from __future__ import annotations

import pytest

from benchmarks import child_scan_pd


@pytest.mark.parametrize("k, low, high", [
    # Garwood's exact two-sided 95 % intervals of a Poisson mean (e.g. Ulm 1990, Am. J. Epidemiol. 131:373)
    (0, 0.0, 3.689), (1, 0.0253, 5.572), (2, 0.2422, 7.225), (5, 1.6235, 11.668), (20, 12.217, 30.889)])
def test_poisson_bounds_are_garwoods(k, low, high):
    lo, hi = child_scan_pd._poisson_bounds(k)
    assert lo == pytest.approx(low, abs=1e-3) and hi == pytest.approx(high, abs=1e-3)


@pytest.mark.parametrize("argv", [["--trials", "0"], ["--averages", "1", "0"]])
def test_bad_counts_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        child_scan_pd.main(argv)
    assert exc.value.code == 2 and "must be >= 1" in capsys.readouterr().err
