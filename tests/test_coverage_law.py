"""The reachability proof's parts (ibt.bt.coverage) on their own: thresholds are snapped to
float32 so that guards no float32 observation tells apart cover alike, and the search over boxes
is exact whichever bound it splits on first (a region it returns meets no box; None only where
the boxes cover every point). Quick: small hand-made trees and boxes."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt import coverage
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Sequence

_ULP = float(np.spacing(np.float32(1.0)))  # 2 ** -23


def _two_guards(low: float, high: float) -> BehaviorTree:
    root = Fallback((Sequence((Condition(0, "<=", low), Action(0))),
                     Sequence((Condition(0, ">", high), Action(1)))))
    return BehaviorTree(root, ("x",), ("a", "b"))


def test_a_threshold_is_snapped_to_the_largest_float32_not_above_it():
    for t in (1.0, 1.0 + 0.4 * _ULP, 1.0 + 0.6 * _ULP, -1.0 - 0.6 * _ULP, 0.1, -0.1, 0.0):
        snapped = coverage._snap(t)
        assert snapped == float(np.float32(snapped)) and snapped <= t
        assert float(np.nextafter(np.float32(snapped), np.float32(np.inf))) > t


def test_guards_with_no_float32_between_them_cover_every_state():
    """``x <= 1 + 0.4 ulp`` rounds down to 1, ``x > 1 + 0.6 ulp`` rounds up past it: no
    float32 lies between the two thresholds, so every observation takes one guard."""
    tree = _two_guards(1.0 + 0.4 * _ULP, 1.0 + 0.6 * _ULP)
    assert coverage.unreached_state(tree) is None
    tree.validate()
    gap = _two_guards(1.0 + 0.4 * _ULP, 1.0 + 1.6 * _ULP)  # 1 + ulp lies between
    state = coverage.unreached_state(gap)
    assert state is not None and state[0] == np.float32(1.0 + _ULP)


_bound = st.sampled_from((-1.0, 0.0, 0.5, 1.0))
_side = st.tuples(_bound, _bound).map(sorted).filter(lambda b: b[0] < b[1]) | st.sampled_from(
    [(-math.inf, 0.0), (0.5, math.inf), (-math.inf, math.inf)])
_box = st.dictionaries(st.integers(0, 2), _side, max_size=3)


def _inside(point: dict[int, float], box: dict) -> bool:
    return all(lo < point.get(f, 0.0) <= hi for f, (lo, hi) in box.items())


@settings(max_examples=200, deadline=None)
@given(st.lists(_box, max_size=6))
def test_the_search_is_exact_whichever_bound_it_splits_on(boxes):
    """On every point of a grid that meets each cell of the bounds: the boxes cover all of them
    exactly where the search finds no region, and a region found meets no box."""
    grid = (-2.0, -1.0, -0.5, 0.0, 0.25, 0.5, 0.75, 1.0, 2.0)
    points = [{0: a, 1: b, 2: c} for a in grid for b in grid for c in grid]
    covered = all(any(_inside(p, box) for box in boxes) for p in points)
    for choose in (coverage._first_cut, coverage._shared_cut):
        region = coverage._search(boxes, choose)
        assert (region is None) is covered
        if region is not None:
            assert all(coverage._meet(region, box) is None for box in boxes)
            assert all(lo < hi for lo, hi in region.values())
    assert (coverage._uncovered(boxes) is None) is covered
    assert (coverage._uncovered(boxes, relational=True) is None) is covered


@settings(max_examples=100, deadline=None)
@given(_box, st.lists(_box, min_size=1, max_size=5))
def test_the_shared_cut_is_a_bound_inside_the_region_that_most_boxes_share(region, live):
    full = (-math.inf, math.inf)
    counts: dict[tuple[int, float], int] = {}
    for box in live:
        for f, (lo, hi) in box.items():
            rlo, rhi = region.get(f, full)
            for cut in (lo, hi):
                if rlo < cut < rhi:
                    counts[(f, cut)] = counts.get((f, cut), 0) + 1
    if not counts:
        return
    feature, cut = coverage._shared_cut(region, live)
    rlo, rhi = region.get(feature, full)
    assert rlo < cut < rhi
    assert counts[(feature, cut)] == max(counts.values())
    assert (feature, cut) == min(k for k, n in counts.items() if n == max(counts.values()))


def test_the_acting_region_is_cut_only_past_max_boxes(monkeypatch):
    """Three guards, three boxes: with a limit of two the third box is still kept (the
    region is cut after it passes the limit), so the proof holds."""
    monkeypatch.setattr(coverage, "MAX_BOXES", 2)
    root = Fallback((Sequence((Condition(0, "<=", 0.0), Action(0))),
                     Sequence((Condition(0, ">", 0.0), Condition(0, "<=", 1.0), Action(1))),
                     Sequence((Condition(0, ">", 1.0), Action(0)))))
    tree = BehaviorTree(root, ("x",), ("a", "b"))
    assert coverage.unreached_state(tree) is None


def test_a_gap_on_two_forms_is_found_with_a_state_in_it():
    """Each form of the BT is a coordinate of its own: a gap where both forms are above their
    thresholds gives a state on which no action is reached."""
    from ibt.bt.linear import LinearForm
    from ibt.bt.model import NO_DECISION

    diff, drift = LinearForm(0, 2, 1.0, -1.0), LinearForm(1, 0, 1.0, -1.0)
    root = Fallback((Sequence((Condition.relational(diff, "<=", 0.0), Action(0))),
                     Sequence((Condition.relational(drift, "<=", 0.0), Action(1)))))
    tree = BehaviorTree(root, ("x", "vx", "target"), ("a", "b"))
    state = coverage.unreached_state(tree)
    assert state is not None and tree.decide(state[None])[0] == NO_DECISION
    assert state[0] - state[2] > 0 and state[1] - state[0] > 0


def test_a_sequence_ending_in_an_acting_fallback_succeeds_only_by_acting():
    """``Fallback(act, c)`` always acts, so a Sequence ending in it succeeds only by acting
    (guarded) even though ``c`` alone is not: the root's default after it is reached on
    every other state, and the BT is proven without a search."""
    inner = Fallback((Action(0), Condition(0, "<=", 0.5)))
    root = Fallback((Sequence((Condition(0, "<=", 0.0), inner)), Action(1)))
    tree = BehaviorTree(root, ("x",), ("a", "b"))
    assert coverage.unreached_state(tree) is None
    facts = coverage._facts(root, {})
    assert facts.acts and facts.guarded
    assert coverage._facts(inner, {}).guarded
