"""The BT model: tick semantics as tables, node counts, JSON, and agreement of executors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt import (
    NO_DECISION,
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Selector,
    Sequence,
    py_trees_decide,
    tick,
    to_py_trees,
)

FEATURES = ("a", "b")
ACTIONS = ("left", "right", "stay")


def bt(root) -> BehaviorTree:
    return BehaviorTree(root, FEATURES, ACTIONS)


A_LOW = Condition(0, "<=", 0.5)
B_HIGH = Condition(1, ">", 0.0)
TREE = bt(Selector((
    Sequence((A_LOW, B_HIGH, Action(0))),
    Sequence((Inverter(A_LOW), Action(1))),
    Action(2),
)))


@pytest.mark.parametrize(("state", "expected"), [
    # Expect: a <= 0.5 and b > 0 -> left; a > 0.5 -> right; otherwise stay
    ((0.0, 1.0), 0),
    ((0.5, 0.1), 0),     # the threshold itself satisfies <=
    ((0.6, 1.0), 1),
    ((0.6, -1.0), 1),
    ((0.0, 0.0), 2),     # b > 0 fails on equality
    ((-3.0, -1.0), 2),
])
def test_tick_table(state, expected):
    assert TREE.decide(np.array([state]))[0] == expected
    decision, _ = tick(TREE, state)
    assert decision == expected


def test_trace_lists_ticked_nodes_with_statuses():
    decision, trace = tick(TREE, (0.6, 1.0))
    assert decision == 1
    labels = [(s.label, s.success) for s in trace]
    # Expect: the first sequence fails at its first condition, the inverter flips it, right runs
    assert labels == [("Selector", True), ("Sequence", False), ("a <= 0.5", False),
                      ("Sequence", True), ("Inverter", True), ("a <= 0.5", False),
                      ("right", True)]


def test_no_decision_when_no_action_reached():
    tree = bt(Sequence((Condition(0, ">", 10.0), Action(0))))
    assert tree.decide(np.zeros((1, 2)))[0] == NO_DECISION


def test_fallback_and_selector_share_semantics():
    for cls in (Fallback, Selector):
        tree = bt(cls((Sequence((Condition(0, ">", 0.0), Action(1))), Action(2))))
        assert tree.decide(np.array([[1.0, 0.0], [-1.0, 0.0]])).tolist() == [1, 2]


def test_node_count_and_types_match_py_trees():
    root, _ = to_py_trees(TREE)
    assert TREE.node_count == len(list(root.iterate())) == 10
    assert TREE.node_types() == {"selector": 1, "sequence": 2, "fallback": 0, "inverter": 1,
                                 "condition": 3, "action": 3}


def test_json_round_trip_and_format():
    doc = TREE.to_dict()
    assert doc["root"]["type"] == "selector"
    assert doc["root"]["children"][0]["children"][0] == {
        "type": "condition", "feature": 0, "op": "<=", "threshold": 0.5}
    assert BehaviorTree.from_json(TREE.to_json()) == TREE


@pytest.mark.parametrize("doc, message", [
    ({"feature_names": ["a"], "action_names": ["x"]}, "root"),
    ({"feature_names": ["a"], "action_names": ["x"], "root": {"type": "banana"}}, "banana"),
    ({"feature_names": ["a"], "action_names": ["x"],
      "root": {"type": "action", "action": 3}}, "action 3"),
    ({"feature_names": ["a"], "action_names": ["x"],
      "root": {"type": "condition", "feature": 0, "op": "<", "threshold": 1}}, "op"),
])
def test_bad_json_is_rejected_with_a_reason(doc, message):
    with pytest.raises(ValueError, match=message):
        BehaviorTree.from_dict(doc)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(-2, 2, width=32), st.floats(-2, 2, width=32)),
                min_size=1, max_size=30))
def test_vectorised_executor_agrees_with_py_trees(states):
    x = np.array(states, dtype=np.float32)
    root, io = to_py_trees(TREE)
    assert np.array_equal(py_trees_decide(root, io, x), TREE.decide(x))
    assert [tick(TREE, row)[0] for row in x] == TREE.decide(x).tolist()


def test_categorical_labels_read_as_categories():
    labels = ((1, ("none", "light", "heavy")),)
    tree = BehaviorTree(Selector((Action(0),)), ("battery", "carrying"), ("go", "stay"), labels)
    # Expect: thresholds between integer codes read as set membership of the labels
    assert tree.label(Condition(1, ">", 1.5)) == "carrying == heavy"
    assert tree.label(Condition(1, "<=", 0.5)) == "carrying == none"
    assert tree.label(Condition(1, "<=", 1.5)) == "carrying != heavy"
    assert tree.label(Condition(0, "<=", 2.5)) == "battery <= 2.5"
    assert BehaviorTree.from_json(tree.to_json()) == tree
