"""States inside polytopes on their own (ibt.bt.polytope): a state passes a test exactly when the
executors' arithmetic says so, a state found lies strictly inside its region (deepest inside,
in the box given or around the thresholds), crossing rows are the last float32 state on each
side of a test, and a BT's regions partition the states by the action it decides. Quick:
small hand-made regions and BTs, one linear program each."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt import polytope
from ibt.bt.linear import LinearForm, ObliqueForm
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Inverter, Selector, Sequence
from ibt.bt.polytope import (
    agreement_rows,
    bt_regions,
    condition_test,
    crossing_rows,
    find_state,
    region_state,
    satisfies,
)

DIFF = LinearForm(0, 2, 1.0, -1.0)  # x - target
SUM3 = ObliqueForm((0, 1, 2), (0.5, 1.0, -2.0))
values32 = st.floats(-100, 100, allow_nan=False, width=32)


def _value(what, x: np.ndarray) -> float:
    """A test's left side as the executors compute it (float32 values widened)."""
    x = np.asarray(x, dtype=np.float32).astype(np.float64)
    if isinstance(what, int):
        return float(x[what])
    total = 0.0
    for k, (f, w) in enumerate(what.terms):
        total = w * x[f] if k == 0 else total + w * x[f]
    return float(total)


tests_strategy = st.lists(st.tuples(st.sampled_from([0, 1, 2, DIFF, SUM3]),
                                    st.floats(-50, 50, allow_nan=False), st.booleans()),
                          min_size=0, max_size=4)


# ------------------------------------------------------------------------------ truth
@settings(max_examples=100, deadline=None)
@given(st.lists(values32, min_size=3, max_size=3), tests_strategy)
def test_a_state_passes_a_region_exactly_where_the_arithmetic_says(row, tests):
    """Law: ``satisfies`` is the conjunction of ``(value <= t) == le`` over the tests."""
    want = all((_value(what, row) <= t) == le for what, t, le in tests)
    assert satisfies(np.asarray(row), tests) == want


def test_a_state_is_read_as_float32_and_a_non_finite_one_passes_nothing():
    # 0.1 as a double is below 0.1 as a float32: the float32 value is what the test reads
    assert float(np.float32(0.1)) > 0.1
    assert not satisfies(np.array([0.1]), [(0, 0.1, True)])
    assert satisfies(np.array([0.1]), [(0, 0.1, False)])
    assert satisfies(np.array([1.0, 2.0]), [])
    assert satisfies(np.array([1.0, 2.0]), [(np.int64(1), 2.0, True)])
    for bad in (math.nan, math.inf, -math.inf, 1e39):
        assert not satisfies(np.array([0.0, bad]), [])
    assert not satisfies(np.array([0.0, 1e39]), [(1, math.inf, True)])


# -------------------------------------------------------------------------- find_state
@settings(max_examples=60, deadline=None)
@given(tests_strategy)
def test_a_state_found_passes_every_test_and_none_means_no_room(tests):
    """Law: a state found passes the region's tests; where none is found, none of many random
    states in the box around the thresholds passes them by more than a hair."""
    state = find_state(3, tests)
    if state is not None:
        assert state.dtype == np.float32 and state.shape == (3,)
        assert satisfies(state, tests)
        return
    rng = np.random.default_rng(0)
    scale = max([1.0, *(2.0 * abs(t) + 1.0 for _, t, _ in tests)])
    rows = rng.uniform(-scale, scale, size=(2000, 3))
    margin = [(what, t - 1e-3 if le else t + 1e-3, le) for what, t, le in tests]
    assert not any(satisfies(r, margin) for r in rows)


def test_the_state_found_is_the_deepest_point_inside():
    """An interval's middle; a box's centre; the middle of the region's part inside the box."""
    assert find_state(1, [(0, 1.0, True), (0, -1.0, False)]).tolist() == [0.0]
    assert find_state(1, [(0, 5.0, True), (0, 3.0, False)]).tolist() == [4.0]
    got = find_state(2, [(0, 4.0, True), (0, 2.0, False), (1, -3.0, True), (1, -5.0, False)])
    assert got.tolist() == [3.0, -4.0]
    # inside the box [0, 10] x [0, 2]: the part x <= 4 is deepest (in box-scaled coordinates)
    # at x = 2, where the box's bound 0 and the test are as far away
    state = find_state(2, [(0, 4.0, True)], [0.0, 0.0], [10.0, 2.0])
    assert state[0] == 2.0 and 0.0 < state[1] < 2.0
    # x - target > 1 in the box [-1, 1]^3: x high and target low, as far from 1 as the box lets
    x = find_state(3, [(DIFF, 1.0, False)], [-1.0] * 3, [1.0] * 3).astype(np.float64)
    assert 1.3 < x[0] - x[2] < 1.5 and 0.6 < x[0] < 0.8 and -0.8 < x[2] < -0.6


def test_the_box_is_the_one_given_when_it_is_a_box_else_one_around_the_thresholds():
    # no box: one around the thresholds (scale 2 |t| + 1), which holds x > 100
    assert 100 < find_state(1, [(0, 100.0, False)])[0] < 201
    # a box that is not one (empty, or not finite, on some feature) is replaced the same way
    for low, high in (([0.0, 0.0], [1.0, 0.0]), ([0.0, -math.inf], [1.0, 1.0]),
                      ([0.0, 0.0], [1.0, math.nan]), ([0.0, 2.0], [1.0, 1.0])):
        state = find_state(2, [(0, 100.0, False), (1, 0.0, True)], low, high)
        assert state is not None and 100 < state[0] < 201
    # a box given that misses the region: searched again in a box a thousand times as wide
    state = find_state(2, [(0, 100.0, False)], [0.0, 0.0], [1.0, 1.0])
    assert state is not None and 100 < state[0] <= 500.5
    assert find_state(1, [(0, 1e6, False)], [0.0], [1.0]) is None  # beyond even that
    # no box given: the box around the thresholds is the only one searched
    slight = LinearForm(0, 1, 1e-3, 1e-3)  # above 1 only where x + y > 1000
    assert find_state(2, [(slight, 1.0, False)]) is None
    assert find_state(2, [(slight, 1.0, False)], [-1.0, -1.0], [1.0, 1.0]) is not None


def test_an_empty_or_flat_region_has_no_state():
    assert find_state(1, [(0, 1.0, True), (0, 1.0, False)]) is None
    assert find_state(1, [(0, 0.0, True), (0, 1.0, False)]) is None
    assert find_state(3, [(DIFF, 0.5, True), (DIFF, 0.5, False)], [-1] * 3, [1] * 3) is None
    # too thin for a float32 point: no float32 value lies in (1, next float32 after 1)
    one = float(np.float32(1.0))
    above = float(np.nextafter(np.float32(1.0), np.float32(2.0)))
    assert find_state(1, [(0, one, False), (0, (one + above) / 2, True)]) is None
    # lower-dimensional: x - target <= 0 and target - x <= 0 hold only on a plane
    plane = [(DIFF, 0.0, True), (LinearForm(2, 0, 1.0, -1.0), 0.0, True)]
    assert find_state(3, plane) is None
    # an infinite threshold does not bound the linear program, but the state still passes it
    state = find_state(1, [(0, math.inf, True), (0, 2.0, False)])
    assert state is not None and state[0] > 2.0


# ------------------------------------------------------------------------ region_state
def test_a_region_of_derived_values_has_a_state_inside_or_a_guess():
    forms = [DIFF]
    state = region_state(3, {3: (0.5, 1.0), 1: (-math.inf, 0.0)}, forms)
    x = state.astype(np.float64)
    assert 0.5 < x[0] - x[2] <= 1.0 and x[1] <= 0.0
    state = region_state(3, {0: (2.0, math.inf), 3: (-math.inf, -4.0)}, forms)
    assert state[0] > 2.0 and state[0] - state[2] <= -4.0
    # an empty region: the middle of its observed bounds is the best guess
    guess = region_state(3, {3: (1.0, 0.5), 0: (-math.inf, 2.5), 1: (7.0, math.inf),
                             2: (-math.inf, math.inf)}, forms)
    assert guess.dtype == np.float32 and guess.tolist() == [2.5, 8.0, 0.0]


# ----------------------------------------------------------------------- crossing rows
@settings(max_examples=60, deadline=None)
@given(st.floats(-1e3, 1e3, allow_nan=False), st.lists(values32, min_size=3, max_size=3),
       st.sampled_from([0, 1, 2]))
def test_crossing_rows_of_a_feature_are_its_last_float32_on_each_side(t, row, feature):
    base = np.asarray(row, dtype=np.float32)
    inside, outside = crossing_rows(feature, t, base)
    assert float(inside[feature]) <= t < float(outside[feature])
    assert np.nextafter(inside[feature], np.float32(np.inf)) == outside[feature]
    others = [f for f in range(3) if f != feature]
    assert np.array_equal(inside[others], base[others])
    assert np.array_equal(outside[others], base[others])
    assert base.tolist() == np.asarray(row, dtype=np.float32).tolist()  # not moved in place


@settings(max_examples=60, deadline=None)
@given(st.sampled_from([DIFF, SUM3, LinearForm(1, 0, -0.5, 3.0), ObliqueForm((2,), (-4.0,))]),
       st.floats(-20, 20, allow_nan=False), st.lists(st.floats(-10, 10, width=32),
                                                      min_size=3, max_size=3))
def test_crossing_rows_of_a_form_are_its_last_state_on_each_side_moving_each_feature(
        form, t, row):
    """Law: for each feature of the form in turn, a pair of states one float32 step apart on
    that feature, the first passing ``<= t`` and the second not."""
    base = np.asarray(row, dtype=np.float32)
    rows = crossing_rows(form, t, base)
    assert len(rows) == 2 * len(form.terms)
    for (moved, _), inside, outside in zip(form.terms, rows[::2], rows[1::2], strict=True):
        assert _value(form, inside) <= t < _value(form, outside)
        assert np.flatnonzero(inside != outside).tolist() == [moved]
        assert np.nextafter(inside[moved], outside[moved]) == outside[moved]
        keep = [f for f in range(3) if f != moved]
        assert np.array_equal(inside[keep], base[keep])


def test_no_crossing_is_found_where_the_first_guess_is_not_finite_or_too_far():
    tiny = LinearForm(0, 1, 1e-300, 1.0)
    rows = crossing_rows(tiny, 1.0, np.array([0.0, 0.0], dtype=np.float32))
    assert len(rows) == 2 and rows[0][1] <= 1.0 < rows[1][1]  # the guess on x0 overflows
    # a weight the float32 guess cannot resolve: more than MAX_STEPS steps from the crossing
    steep = LinearForm(0, 1, 1.0, 1e-12)
    base = np.array([0.0, 0.0], dtype=np.float32)
    assert polytope._crossing(steep, 0.5, base, 1, np.float32(0.0), True) == []
    assert polytope._crossing(DIFF, 0.0, np.zeros(3, np.float32), 0, np.float32(np.inf),
                              True) == []
    assert polytope._crossing(DIFF, 0.0, np.zeros(3, np.float32), 0, np.float32(1e6),
                              True) == []


def test_a_feature_s_crossing_at_a_float32_threshold_is_that_value_and_the_next():
    base = np.zeros(2, dtype=np.float32)
    inside, outside = crossing_rows(1, 0.5, base)
    assert inside.tolist() == [0.0, 0.5]
    assert outside.tolist() == [0.0, float(np.nextafter(np.float32(0.5), np.float32(1.0)))]
    inside, outside = crossing_rows(np.int64(0), -0.1, base)  # -0.1 lies between float32s
    assert float(inside[0]) <= -0.1 < float(outside[0]) and inside[1] == outside[1] == 0.0


def _steps(value: float, k: int) -> np.float32:
    """``k`` float32 steps from ``value`` (up for positive ``k``)."""
    v = np.float32(value)
    for _ in range(abs(k)):
        v = np.nextafter(v, np.float32(np.inf if k > 0 else -np.inf))
    return v


def test_a_crossing_is_searched_at_most_max_steps_from_the_first_guess_on_each_side():
    """``x - target <= 0.5`` moving x (base 0): the crossing is at 0.5. A guess 255 float32
    steps past it is walked back to it, one 256 steps past is given up; from inside, a guess
    255 steps below reaches the first state past it, one 256 steps below does not."""
    assert polytope.MAX_STEPS == 256
    base = np.zeros(3, dtype=np.float32)

    def crossing(k: int) -> list[np.ndarray]:
        return polytope._crossing(DIFF, 0.5, base, 0, _steps(0.5, k), True)

    for k in (255, -255):
        inside, outside = crossing(k)
        assert inside[0] == np.float32(0.5) and outside[0] == _steps(0.5, 1)
    assert crossing(256) == [] and crossing(-256) == []


def test_a_crossing_search_walks_from_either_side_of_the_threshold():
    base = np.zeros(3, dtype=np.float32)
    for guess in (np.float32(0.5), np.float32(0.5 - 1e-6), np.float32(0.5 + 1e-6)):
        # x - 0 <= 0.5 up to x = 0.5; 0 - target <= -0.5 from target = 0.5 on
        for form, moved, rising, t in ((DIFF, 0, True, 0.5), (DIFF, 2, False, -0.5)):
            inside, outside = polytope._crossing(form, t, base, moved, guess, rising)
            assert _value(form, inside) <= t < _value(form, outside)
            assert np.nextafter(inside[moved], outside[moved]) == outside[moved]


# ------------------------------------------------------------------------ a BT's regions
def _bt(root) -> BehaviorTree:
    return BehaviorTree(root, ("x", "y", "target"), ("left", "stay", "right"))


TREES = {
    "relational": Selector((Sequence((Condition.relational(DIFF, "<=", -0.5), Action(2))),
                            Sequence((Condition.relational(DIFF, ">", 0.5), Action(0))),
                            Action(1))),
    "inverted": Selector((Sequence((Inverter(Condition(1, ">", 0.0)),
                                    Condition.relational(SUM3, "<=", 1.0), Action(0))),
                          Fallback((Sequence((Condition(0, "<=", -1.0), Action(2))),
                                    Action(1))))),
    "fallback first": Fallback((Sequence((Fallback((Condition(0, "<=", 0.0),
                                                    Condition(1, "<=", 0.0))), Action(1))),
                                Action(0))),
}


@pytest.mark.parametrize("name", list(TREES))
def test_a_bt_s_regions_partition_the_states_by_the_action_it_decides(name):
    """Law: every state passes the tests of exactly one region (of those it reaches), whose
    action is the BT's decision there."""
    bt = _bt(TREES[name])
    regions = bt_regions(bt)
    rng = np.random.default_rng(1)
    states = rng.uniform(-3, 3, size=(400, 3)).astype(np.float32)
    decided = bt.decide(states)
    for state, action in zip(states, decided, strict=True):
        inside = [a for tests, a in regions if satisfies(state, tests)]
        assert inside == [action]
    for tests, action in regions:  # and each region holds a state the BT sends there
        state = find_state(3, tests)
        assert state is not None and bt.decide(state[None])[0] == action


def test_the_regions_of_a_bt_follow_its_conditions():
    bt = _bt(TREES["relational"])
    assert sorted((len(tests), action) for tests, action in bt_regions(bt)) == [
        (1, 2), (2, 0), (2, 1)]
    assert bt_regions(_bt(Selector((Action(1),)))) == [((), 1)]
    assert len(bt_regions(bt, max_regions=2)) == 2
    # a condition no float32 state fails decides nothing: no split
    top = float(np.finfo(np.float32).max)
    always = Selector((Sequence((Condition(0, "<=", top), Action(2))), Action(0)))
    assert bt_regions(_bt(always)) == [((), 2)]


def test_a_condition_as_a_test_holds_or_fails_as_its_operator_says():
    le, gt = Condition(1, "<=", 0.5), Condition.relational(DIFF, ">", -2.0)
    assert condition_test(le) == (1, 0.5, True) and condition_test(le, False) == (1, 0.5, False)
    assert condition_test(gt) == (DIFF, -2.0, False)
    assert condition_test(gt, le=False) == (DIFF, -2.0, True)


def test_agreement_rows_hold_a_state_in_every_region_its_crossings_and_the_random_ones():
    bt = _bt(TREES["relational"])
    random = np.random.default_rng(2).uniform(-1, 1, size=(7, 3)).astype(np.float32)
    rows = agreement_rows(bt, [-1.0] * 3, [1.0] * 3, random)
    assert rows.dtype == np.float32 and rows.shape[1] == 3
    assert np.array_equal(rows[-7:], random)
    assert sorted(set(bt.decide(rows[:-7]).tolist())) == [0, 1, 2]
    z = rows[:-7].astype(np.float64) @ np.array([1.0, 0.0, -1.0])
    for t in (-0.5, 0.5):  # both sides of each test, one float32 step apart
        assert (z <= t).any() and (z > t).any()
        closest_in, closest_out = z[z <= t].max(), z[z > t].min()
        assert closest_out - closest_in < 1e-6
    # a state in each of the 3 regions, each region's tests crossed (2 rows per feature of a
    # form, 2 forms' tests in two regions, 1 in one), both conditions crossed next to a
    # random state, then the random states
    assert len(rows) == 3 + 4 * (1 + 2 + 2) + 2 * 4 + 7
    # each condition crossed next to a random state drawn with the seed (0 by default): every
    # crossing row of a form over x and target keeps that state's y
    rng = np.random.default_rng(0)
    picks = [int(rng.integers(7)) for _ in range(2)]
    assert rows[-15:-7, 1].tolist() == [random[picks[0], 1]] * 4 + [random[picks[1], 1]] * 4
    rng = np.random.default_rng(9)
    picks = [int(rng.integers(7)) for _ in range(2)]
    again = agreement_rows(bt, [-1.0] * 3, [1.0] * 3, random, seed=9)
    assert again[-15:-7, 1].tolist() == [random[picks[0], 1]] * 4 + [random[picks[1], 1]] * 4
    empty = agreement_rows(bt, [-1.0] * 3, [1.0] * 3, np.zeros((0, 3), np.float32))
    assert len(empty) == 3 + 4 * 5
