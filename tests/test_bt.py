"""The BT model: tick semantics as tables, node counts, JSON, and agreement of executors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.executors import py_trees_decide, tick, to_py_trees
from ibt.bt.model import (
    NO_DECISION,
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Selector,
    Sequence,
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


# ------------------------------------------------------------- node identity, shapes, proofs
def test_a_node_object_used_twice_gets_two_positions_in_trace_and_drawing():
    from ibt.bt.model import indexed
    from ibt.export.drawing import drawing_elements, to_graphviz

    # TREE uses the one object A_LOW twice (positions 2 and 7 in depth-first order)
    positions = [i for i, (node, _) in enumerate(indexed(TREE.root)) if node is A_LOW]
    assert positions == [2, 7]
    _, trace = tick(TREE, (0.6, 1.0))
    # Expect: the trace names each ticked node by its own position (the first A_LOW by 2)
    assert [(s.index, s.label) for s in trace] == [
        (0, "Selector"), (1, "Sequence"), (2, "a <= 0.5"), (5, "Sequence"), (6, "Inverter"),
        (7, "a <= 0.5"), (8, "right")]
    # the drawing shows every position, the two A_LOW positions in two places (rows)
    elements = drawing_elements(TREE)
    assert sorted(elements) == list(range(TREE.node_count))
    assert elements[2] != elements[7]
    # Expect: highlighting position 2 marks one row only, not position 7's
    source = to_graphviz(TREE, highlight={2: False}, legend=False).source
    assert source.count("✗") == 1 and "✓" not in source


@pytest.mark.parametrize(("call", "message"), [
    (lambda: TREE.decide(np.zeros(2)), r"shape \(n, 2\)"),
    (lambda: TREE.decide(np.zeros((3, 3))), r"shape \(n, 2\)"),
    (lambda: TREE.decide(np.zeros((3, 1))), r"shape \(n, 2\)"),
    (lambda: tick(TREE, np.zeros((1, 2))), r"one state of shape \(2,\)"),
    (lambda: tick(TREE, np.zeros(3)), r"one state of shape \(2,\)"),
    (lambda: py_trees_decide(*to_py_trees(TREE), np.zeros(2)), r"shape \(n, 2\)"),
])
def test_executors_take_exact_shapes(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_py_trees_decides_a_batch_of_one():
    root, io = to_py_trees(TREE)
    assert py_trees_decide(root, io, np.array([[0.6, 1.0]])).tolist() == [1]


def _proven(tree: BehaviorTree) -> bool:
    try:
        tree.validate()
    except ValueError as err:
        assert "reach" in str(err)
        return False
    return True


@pytest.mark.parametrize(("root", "proven"), [
    # Expect: a default, a tree-shaped Fallback, and guards that cover the line are proven
    (Selector((Sequence((A_LOW, Action(0))), Action(1))), True),
    (Fallback((Sequence((A_LOW, Fallback((Sequence((B_HIGH, Action(0))), Action(1))))),
               Action(2))), True),
    (Selector((Sequence((Condition(0, "<=", 0.0), Action(0))),
               Sequence((Inverter(Condition(0, "<=", 0.0)), Action(1))))), True),
    # two thresholds no float32 observation tells apart: the guards still cover every state
    (Selector((Sequence((Condition(0, "<=", 0.1), Action(0))),
               Sequence((Condition(0, ">", 0.10000000001), Action(1))))), True),
    # Expect: a gap between guards, a bare condition before the default, no action at all
    (Selector((Sequence((Condition(0, "<=", 0.0), Action(0))),
               Sequence((Condition(0, ">", 0.5), Action(1))))), False),
    (Selector((A_LOW, Action(1))), False),
    (Sequence((A_LOW, B_HIGH)), False),
])
def test_validate_proves_that_every_state_reaches_an_action(root, proven):
    assert _proven(bt(root)) is proven


def test_a_gap_is_reported_with_a_state_inside_it():
    from ibt.bt.coverage import unreached_state

    tree = bt(Selector((Sequence((Condition(0, "<=", 0.0), Action(0))),
                        Sequence((Condition(0, ">", 0.5), Action(1))))))
    state = unreached_state(tree)
    assert state is not None and 0.0 < state[0] <= 0.5
    assert tree.decide(state[None])[0] == NO_DECISION
    with pytest.raises(ValueError, match="no action is reached on some states"):
        tree.validate()


THRESHOLDS = (-1.0, 0.0, 0.5, 1.0)
# one state in every cell of the threshold grid, and on every threshold
PROBES = np.array([(a, b) for a in (-2, -1, -0.5, 0, 0.25, 0.5, 0.75, 1, 2)
                   for b in (-2, -1, -0.5, 0, 0.25, 0.5, 0.75, 1, 2)], dtype=np.float32)
_leaves = (st.builds(Condition, st.integers(0, 1), st.sampled_from(("<=", ">")),
                     st.sampled_from(THRESHOLDS))
           | st.builds(Action, st.integers(0, 2)))
_nodes = st.recursive(_leaves, lambda kids: (
    st.builds(Inverter, kids)
    | st.builds(Sequence, st.lists(kids, min_size=1, max_size=3).map(tuple))
    | st.builds(Fallback, st.lists(kids, min_size=1, max_size=4).map(tuple))), max_leaves=12)


@settings(max_examples=300, deadline=None)
@given(_nodes)
def test_validate_is_sound(root):
    # Law: a BT that validates reaches an action on every state (the probes cover every cell
    # of the thresholds' grid), and a reported unreached state is one
    tree = bt(root)
    reached = tree.decide(PROBES) != NO_DECISION
    try:
        tree.validate()
    except ValueError as err:
        if "no action is reached" in str(err):
            assert not reached.all()
    else:
        assert reached.all()


def test_every_committed_bt_loads_and_is_proven():
    from pathlib import Path

    from ibt.bt.json_io import load_json

    files = sorted(Path(__file__).parents[1].glob("data/trees/*/*/*.json"))
    assert len(files) >= 24
    for path in files:
        load_json(path)  # from_dict validates: indices, thresholds, reachability
