"""The deadline's arithmetic on a fake clock (:mod:`ibt.engine.deadline`): when a budget has
passed, what is left, the grace a step under way gets, a budget that reserves time for later
work, and the pace that foretells the least a step can take. Quick; the ladder's use of them is
in ``tests/test_deadline.py``."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.engine import deadline as deadline_module
from ibt.engine.deadline import Deadline, Pace
from ibt.engine.measure import Returns


class Clock:
    """A clock that moves only when told."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def test_a_budget_passes_at_its_last_second_and_not_before():
    clock = Clock()
    deadline = Deadline(10.0, clock)
    assert deadline.start == 100.0 and deadline.elapsed() == 0.0 and deadline.left() == 10.0
    clock.now = 109.5
    assert not deadline.passed() and deadline.elapsed() == 9.5 and deadline.left() == 0.5
    clock.now = 110.0
    assert deadline.passed() and deadline.left() == 0.0
    clock.now = 112.0
    assert deadline.passed() and deadline.left() == -2.0


def test_no_limit_never_passes_and_has_no_grace():
    clock = Clock()
    deadline = Deadline(None, clock)
    clock.now = 1e12
    assert not deadline.passed() and deadline.left() == math.inf and deadline.grace() == 0.0
    assert deadline.elapsed() == 1e12 - 100.0
    inner = deadline.reserving(30.0)
    assert inner.seconds is None and not inner.passed() and inner.grace() == 0.0


def test_the_default_clock_is_the_monotonic_one():
    deadline = Deadline(3600.0)
    assert 0.0 <= deadline.elapsed() < 60.0 and not deadline.passed()


@given(seconds=st.floats(0.0, 1e6))
def test_the_grace_is_a_share_of_the_budget_and_at_least_the_minimum(seconds):
    grace = Deadline(seconds, Clock()).grace()
    assert grace == max(deadline_module.GRACE_MIN, deadline_module.GRACE_SHARE * seconds)


def test_the_grace_values():
    assert deadline_module.GRACE_SHARE == 0.1 and deadline_module.GRACE_MIN == 60.0
    assert Deadline(100.0, Clock()).grace() == 60.0
    assert Deadline(1800.0, Clock()).grace() == 180.0


@given(seconds=st.floats(0.0, 1e5), reserved=st.floats(0.0, 1e5), later=st.floats(0.0, 1e5))
def test_a_reserving_budget_is_the_same_start_less_the_reserve_and_the_same_grace(
        seconds, reserved, later):
    clock = Clock()
    outer = Deadline(seconds, clock)
    clock.now += 5.0
    inner = outer.reserving(reserved)
    assert inner.start == outer.start and inner.clock is clock
    assert inner.seconds == max(seconds - reserved, 0.0)
    assert inner.grace() == outer.grace()
    clock.now += later
    assert inner.elapsed() == outer.elapsed()
    assert inner.passed() == (clock.now - 100.0 >= max(seconds - reserved, 0.0))


def test_a_reserve_past_the_budget_leaves_none():
    inner = Deadline(10.0, Clock()).reserving(25.0)
    assert inner.seconds == 0.0 and inner.passed() and inner.grace() == 60.0


def _returns(lengths: list[int] | None, seconds: float | None) -> Returns:
    return Returns(returns=[0.0] * len(lengths or [1]), first_seed=0, lengths=lengths,
                   seconds=seconds)


def test_the_pace_counts_only_measurements_rolled_out_now():
    pace = Pace()
    assert pace.least(100) == 0.0 and pace.length() == math.inf
    pace.add(_returns([10, 30], None))  # read from the cache: no wall time
    pace.add(_returns(None, 3.0))  # lengths unknown
    pace.add(_returns([], 3.0))  # no episode
    assert (pace.seconds, pace.steps, pace.episodes) == (0.0, 0, 0)
    pace.add(_returns([10, 30], 2.0))
    pace.add(_returns([20], 1.0))
    assert (pace.seconds, pace.steps, pace.episodes) == (3.0, 60, 3)
    assert pace.length() == 20.0
    assert pace.least(4) == pytest.approx(4 * 20.0 * 3.0 / 60)
    assert pace.said(1500) == ("1,500 episodes of 20 steps at the 50000 us a step this run's "
                               "tree measurements took")


def test_the_shorter_of_the_agents_and_the_trees_episodes_sets_the_pace():
    pace = Pace(agent_length=5.0)
    assert pace.length() == 5.0
    pace.add(_returns([10, 10], 2.0))
    assert pace.length() == 5.0 and pace.least(2) == pytest.approx(2 * 5.0 * 0.1)
    uneven = Pace()
    uneven.add(_returns([10, 11], 2.1))
    assert uneven.length() == 10.5 and uneven.least(2) == pytest.approx(2.1)
    longer = Pace(agent_length=50.0)
    longer.add(_returns([10, 10], 2.0))
    assert longer.length() == 10.0
    none = Pace(agent_length=0.0)  # no agent length known: the trees' mean alone
    none.add(_returns([10, 10], 2.0))
    assert none.length() == 10.0


@given(limit=st.floats(10, 1e5), share=st.floats(0, 2))
def test_a_time_stop_says_whether_the_budget_ran_out_or_the_next_step_would_not_fit(
        limit: float, share: float) -> None:
    """A run that stops well before its budget's end says the next step would not fit in what
    was left (not that the budget ran out), with what was left; one that reached its end says
    it ran out."""
    from types import SimpleNamespace

    from ibt.pipeline.recommend import Recommendation

    rec = SimpleNamespace(time_limit=limit, elapsed=share * limit)
    said = Recommendation.time_stop.fget(rec)  # type: ignore[attr-defined]
    if share < 0.95:
        assert said.startswith("what was left of its --time budget (")
        assert f"({limit - share * limit:.0f} s)" in said and "would not cover" in said
    else:
        assert said == "its --time budget ran out"
