"""A smaller averaging ceiling for the linearization of tests that range, not grade, the chirp.

``lidard.instrument.calibration.linearization.MAX_AVERAGES`` (2048) is how far the ILC may double its
averages per measurement when the noise floor stops learning above its target; on the broad-linewidth
laser it doubles all the way, and the 1024- and 2048-record steps are most of a linearization's CPU
(116 s of the 132 s of CPU of tests/e2e/test_e2e_quadrature_far_wall.py). A far-wall test asserts
what the scan ranges with the learned chirp, not how far the ILC got, and at 256 the learned chirp
still ranges every pixel of those tests (a >= 200x reduction; measured in docs/measured/28_suite_cpu.md).
Tests that grade the ILC itself (tests/dsp/linearize/test_dsp_ilc.py) keep their own ceilings.

Use ``with capped_ilc_averages(256): cal = inst.linearize()`` (module-scoped fixtures cannot take the
function-scoped ``monkeypatch``). The attribute must exist: a renamed constant fails here, loudly.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import pytest

import lidard.instrument.calibration.linearization as linearization


@contextlib.contextmanager
def capped_ilc_averages(max_averages: int) -> Iterator[None]:
    """Within the block, the linearization's averages stop doubling at ``max_averages``."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(linearization, "MAX_AVERAGES", int(max_averages), raising=True)
        yield
