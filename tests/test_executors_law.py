"""The three executors of a Behavior Tree (``tick``, ``decide_batch``, py_trees) obey one law:
a tick visits the tree depth first, a Sequence stops at its first failure, a Fallback at its
first success, an Inverter flips, an Action succeeds, and **the first action reached
decides** (later actions a tick still reaches change nothing). A reference interpreter written
from that law is checked against all three on random trees, including trees that reach
several actions in one tick."""

from __future__ import annotations

from dataclasses import FrozenInstanceError

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ibt.bt.executors import decide_batch, py_trees_decide, tick, to_py_trees
from ibt.bt.model import (
    NO_DECISION,
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Node,
    Selector,
    Sequence,
)

N_FEATURES, N_ACTIONS = 2, 4
FEATURES = tuple(f"x{i}" for i in range(N_FEATURES))
ACTIONS = tuple(f"a{i}" for i in range(N_ACTIONS))


def reference(node: Node, x: np.ndarray, decided: list[int]) -> bool:
    """The law, for one state: the status of ``node``; the first action reached is appended
    to ``decided`` (every later one too: only ``decided[0]`` decides)."""
    if isinstance(node, Condition):
        return bool(node.holds(x))
    if isinstance(node, Action):
        decided.append(node.action)
        return True
    if isinstance(node, Inverter):
        return not reference(node.child, x, decided)
    want = isinstance(node, Sequence)  # a Sequence goes on while its children succeed
    for child in node.children:
        if reference(child, x, decided) != want:
            return not want
    return want


def decision(root: Node, x: np.ndarray) -> int:
    decided: list[int] = []
    reference(root, x, decided)
    return decided[0] if decided else NO_DECISION


conditions = st.builds(Condition, st.integers(0, N_FEATURES - 1), st.sampled_from(["<=", ">"]),
                       st.sampled_from([-0.5, 0.0, 0.5]))
actions = st.builds(Action, st.integers(0, N_ACTIONS - 1))
nodes = st.recursive(
    conditions | actions,
    lambda kids: (st.builds(Sequence, st.lists(kids, min_size=1, max_size=3).map(tuple))
                  | st.builds(Fallback, st.lists(kids, min_size=1, max_size=3).map(tuple))
                  | st.builds(Inverter, kids)),
    max_leaves=10)
STATES = np.array([[a, b] for a in (-1.0, -0.5, 0.0, 0.25, 1.0) for b in (-0.7, 0.0, 0.5)])


def _three_executors(root: Node, states: np.ndarray) -> dict[str, list[int]]:
    bt = BehaviorTree(root, FEATURES, ACTIONS)
    py_root, io = to_py_trees(bt)
    return {"tick": [tick(bt, s)[0] for s in states],
            "decide_batch": decide_batch(root, states).tolist(),
            "py_trees": py_trees_decide(py_root, io, states).tolist()}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(root=nodes)
def test_every_executor_decides_as_the_law_on_random_trees(root):
    """Mutants: any executor taking the last action reached, a Sequence or Fallback that does
    not stop where it should, an Inverter that does not flip."""
    expected = [decision(root, s) for s in STATES]
    for name, got in _three_executors(root, STATES).items():
        assert got == expected, name


@pytest.mark.parametrize("root", [
    Sequence((Action(1), Action(2))),
    Selector((Sequence((Action(3), Condition(0, ">", 9.0))), Action(0))),
    Fallback((Inverter(Action(2)), Sequence((Action(1), Action(3))))),
], ids=["sequence-of-actions", "failed-sequence-after-an-action", "inverted-action"])
def test_the_first_action_reached_decides(root):
    """Mutants: ``decision == NO_DECISION`` guards removed or inverted (the last action a tick
    reaches would decide) in ``_tick_mask``, ``tick`` and the py_trees action."""
    state = np.zeros((1, N_FEATURES))
    first = next(_actions_in_order(root)).action  # each case reaches its first action first
    assert decision(root, state[0]) == first
    for name, got in _three_executors(root, state).items():
        assert got == [first], name


def _actions_in_order(node: Node):
    if isinstance(node, Action):
        yield node
    for child in getattr(node, "children", ()):
        yield from _actions_in_order(child)


def test_a_tick_records_each_node_once_with_its_status_in_depth_first_order():
    """Mutants: a composite's status recorded before its children ran, or positions shifted."""
    root = Selector((Sequence((Condition(0, ">", 0.0), Action(1))), Action(0)))
    bt = BehaviorTree(root, FEATURES, ACTIONS)
    action, trace = tick(bt, [-1.0, 0.0])
    assert action == 0
    assert [(s.index, s.depth, s.success) for s in trace] == [
        (0, 0, True), (1, 1, False), (2, 2, False), (4, 1, True)]
    action, trace = tick(bt, [1.0, 0.0])
    assert action == 1
    assert [(s.index, s.success) for s in trace] == [(0, True), (1, True), (2, True), (3, True)]
    inverted = BehaviorTree(Selector((Sequence((Inverter(Condition(0, "<=", 0.0)), Action(1))),
                                      Action(0))), FEATURES, ACTIONS)
    action, trace = tick(inverted, [1.0, 0.0])
    with pytest.raises(FrozenInstanceError):  # a trace is a record: mutant ``frozen=False``
        trace[0].success = False  # type: ignore[misc]
    assert action == 1
    assert [(s.index, s.depth, s.success, s.label) for s in trace] == [
        (0, 0, True, "Selector"), (1, 1, True, "Sequence"), (2, 2, True, "Inverter"),
        (3, 3, False, "x0 <= 0"), (4, 2, True, "a1")]
    shallow = BehaviorTree(Sequence((Inverter(Condition(0, ">", 0.0)), Action(1))), FEATURES,
                           ACTIONS)  # an Inverter at an odd depth: mutant ``depth ^ 1``
    assert [(s.index, s.depth, s.success) for s in tick(shallow, [-1.0, 0.0])[1]] == [
        (0, 0, True), (1, 1, True), (2, 2, False), (3, 1, True)]


def test_decide_batch_takes_a_batch_and_nothing_else():
    """Mutant: the refusal of a state that is not a batch (``x.ndim != 2``) removed or
    inverted."""
    root = Selector((Sequence((Condition(0, ">", 0.0), Action(1))), Action(0)))
    with pytest.raises(ValueError, match=r"batch of shape \(n, n_features\), got shape \(2,\)"):
        decide_batch(root, np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="got shape"):
        decide_batch(root, np.zeros((1, 2, 2)))
    assert decide_batch(root, np.array([[1.0, 0.0], [-1.0, 0.0]])).tolist() == [1, 0]
    assert decide_batch(root, np.zeros((0, 2))).tolist() == []


def test_tick_and_py_trees_refuse_a_state_of_the_wrong_shape():
    """Mutants: the shape checks of ``tick`` and ``py_trees_decide`` removed or inverted."""
    bt = BehaviorTree(Selector((Sequence((Condition(0, ">", 0.0), Action(1))), Action(0))),
                      FEATURES, ACTIONS)
    with pytest.raises(ValueError, match=r"one state of shape \(2,\)"):
        tick(bt, [0.0, 0.0, 0.0])
    root, io = to_py_trees(bt)
    with pytest.raises(ValueError, match=r"batch of shape \(n, 2\)"):
        py_trees_decide(root, io, np.zeros(2))
    with pytest.raises(ValueError, match=r"batch of shape \(n, 2\)"):
        py_trees_decide(root, io, np.zeros((3, 3)))


def test_no_action_reached_is_no_decision_in_every_executor():
    """Mutant: the initial ``NO_DECISION`` of any executor replaced by an action index."""
    root = Sequence((Condition(0, ">", 5.0), Action(2)))
    assert all(got == [NO_DECISION] for got in _three_executors(root, np.zeros((1, 2))).values())
