"""Fixtures of the fault-injection tests: a started simulated bench with in-process USB."""

import pytest

from tests.helpers.sim_bench import started_bench


@pytest.fixture
def bench():
    with started_bench() as b:
        yield b
