"""drivers.retry.RetryPolicy: the tries, the exponential backoff on the injected clock, which errors
are retried, and bad settings named."""

from __future__ import annotations

import pytest

from drivers.errors import InvalidValue
from drivers.retry import RetryPolicy


def test_tries_wait_the_doubling_backoff_before_each_retry():
    slept: list[float] = []
    policy = RetryPolicy(4, 0.01, slept.append)
    seen = []
    for attempt in policy.tries():
        seen.append((attempt, list(slept)))
    assert [a for a, _ in seen] == [0, 1, 2, 3]
    assert seen[0][1] == []                                  # the first try does not wait
    assert slept == pytest.approx([0.01, 0.02, 0.04])
    # the total wait is bounded: backoff * (2**(attempts-1) - 1)
    assert sum(slept) == pytest.approx(0.01 * (2 ** 3 - 1))
    assert [policy.delay_s(k) for k in range(4)] == pytest.approx([0.0, 0.01, 0.02, 0.04])


def test_retries_counts_the_first_try_too_and_a_zero_backoff_never_sleeps():
    slept: list[float] = []
    policy = RetryPolicy.retries(2, 0.0, slept.append)
    assert policy.attempts == 3
    assert list(policy.tries()) == [0, 1, 2] and slept == []


def test_call_retries_only_the_named_errors_and_reports_each_retry():
    slept: list[float] = []
    outcomes = iter([TimeoutError("t1"), TimeoutError("t2"), "ok"])

    def fn() -> str:
        out = next(outcomes)
        if isinstance(out, Exception):
            raise out
        return out

    retried: list[tuple[int, str]] = []
    policy = RetryPolicy(3, 0.5, slept.append, retry_on=(TimeoutError,))
    assert policy.call(fn, on_retry=lambda k, e: retried.append((k, str(e)))) == "ok"
    assert retried == [(0, "t1"), (1, "t2")] and slept == [0.5, 1.0]

    def refused() -> None:
        raise ValueError("no")

    with pytest.raises(ValueError, match="no"):     # not in retry_on: no second try
        RetryPolicy(3, 0.5, slept.append, retry_on=(TimeoutError,)).call(refused)
    assert slept == [0.5, 1.0]


def test_call_raises_the_last_error_when_the_tries_run_out():
    calls = []

    def always() -> None:
        calls.append(1)
        raise TimeoutError(f"try {len(calls)}")

    with pytest.raises(TimeoutError, match="try 2"):
        RetryPolicy(2, 0.0, retry_on=(TimeoutError,)).call(always)
    assert len(calls) == 2


@pytest.mark.parametrize("kwargs, word", [
    ({"attempts": 0}, "attempts"), ({"attempts": True}, "attempts"), ({"attempts": 1.5}, "attempts"),
    ({"attempts": 2, "backoff_s": -1.0}, "backoff_s"), ({"attempts": 2, "backoff_s": float("inf")}, "backoff_s"),
    ({"attempts": 2, "sleep": 3}, "sleep"),
])
def test_bad_settings_are_named(kwargs, word):
    with pytest.raises(InvalidValue, match=word):
        RetryPolicy(**kwargs)
