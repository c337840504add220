"""A controller tree as a BT on its own (ibt.synth.controller): each split is one test (a plain
feature test where it reads one feature with weight 1), each leaf one rule sending its linear
command, the layout the smaller of a split's two orders, the check refusing a BT that sends
another command and counting where, the check's states, and the rules read as if/elif/else.
Quick: hand-made trees of three to four leaves, no learner."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.linear import LinearForm, ObliqueForm
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Selector, Sequence
from ibt.distill.controller import ControllerArrays, widen
from ibt.distill.oblique import ObliqueArrays
from ibt.synth import controller as synth
from ibt.synth.controller import (
    check_states,
    controller_bt,
    leaf_commands,
    rule_names,
    rules_text,
    split_condition,
)
from ibt.tasks.catalogue import get_task

PENDULUM = get_task("Pendulum-v1")  # cos_theta, sin_theta, angular_velocity -> torque
CARTPOLE = get_task("CartPole-v1")  # four features, two actions
SPLITS = {"axis": [1.0, 0.0, 0.0], "scaled": [0.0, 2.0, 0.0], "pair": [0.0, 0.5, -1.0],
          "three": [0.25, 1.0, -2.0]}


def _tree(shape: str, splits=("axis", "pair", "three"), seed: int = 0, bias=None):
    """A controller tree on Pendulum's three features: ``right`` (root, a leaf on the left,
    a split on the right), ``left`` (mirrored) or ``both`` (two splits below the root)."""
    left, right = {"right": ([1, -1, 3, -1, -1], [2, -1, 4, -1, -1]),
                   "left": ([1, 3, -1, -1, -1], [2, 4, -1, -1, -1]),
                   "both": ([1, 3, 5, -1, -1, -1, -1], [2, 4, 6, -1, -1, -1, -1])}[shape]
    n = len(left)
    rng = np.random.default_rng(seed)
    split, threshold = np.zeros((n, 3)), np.zeros(n)
    inner = [k for k in range(n) if left[k] != -1]
    for k, name in zip(inner, splits, strict=False):
        split[k] = SPLITS[name]
        threshold[k] = round(float(rng.normal()) * 0.5, 3)
    bias = rng.normal(size=(n, 1)).round(3) if bias is None else np.asarray(bias, float)
    weights = np.zeros((n, 1, 3))
    for k in range(n):
        if left[k] == -1:
            weights[k, 0, rng.choice(3, size=2, replace=False)] = rng.normal(size=2).round(2)
    bias[inner] = 0.0
    return ControllerArrays(np.array(left), np.array(right), split, threshold, bias, weights)


def _states(tree, n: int = 300, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return check_states(tree, PENDULUM, rng.uniform(-1.5, 1.5, size=(n, 3)), seed=seed,
                        n_random=200)


# ------------------------------------------------------------------------- split tests
def test_a_split_is_a_plain_test_only_where_it_reads_one_feature_with_weight_one():
    tree = _tree("both", splits=("axis", "scaled", "pair"))
    tree = tree.with_parameters(tree.threshold, tree.bias, tree.weights,
                                split=np.vstack([tree.split[:3], [SPLITS["three"]],
                                                 tree.split[4:]]))
    plain = split_condition(tree, 0, "<=")
    assert plain == Condition(0, "<=", float(tree.threshold[0])) and plain.form is None
    assert type(plain.threshold) is float
    scaled = split_condition(tree, 1, ">")
    assert scaled.form == ObliqueForm((1,), (2.0,)) and scaled.op == ">"
    assert split_condition(tree, 2, "<=").form == LinearForm(1, 2, 0.5, -1.0)
    assert split_condition(tree, 3, ">").form == ObliqueForm((0, 1, 2), (0.25, 1.0, -2.0))
    assert split_condition(tree, 2, ">").threshold == float(tree.threshold[2])


# ---------------------------------------------------------------------- leaf commands
def test_leaves_are_numbered_depth_first_left_first_and_send_their_commands():
    tree = _tree("left", bias=[[0.0], [0.0], [-0.0], [1.5], [-2.0]])
    order, commands = leaf_commands(tree, PENDULUM)
    assert order == [3, 4, 2]
    assert commands.dimensions == ("torque",) and commands.units == ("N m",)
    assert commands.values == ((1.5,), (-2.0,), (0.0,))
    assert math.copysign(1.0, commands.values[2][0]) == 1.0  # -0.0 is written as 0.0
    for k, leaf in enumerate(order):
        want = tuple((int(f), float(tree.weights[leaf, 0, f]))
                     for f in np.flatnonzero(tree.weights[leaf, 0]))
        assert commands.terms[k] == (want,) and want
    _, unitless = leaf_commands(tree, replace(PENDULUM, action_units=()))
    assert unitless.units == ("",)
    deep = _tree("both")
    assert leaf_commands(deep, PENDULUM)[0] == [3, 4, 5, 6]


def test_rules_are_named_by_what_they_send_and_numbered_only_where_two_read_alike():
    tree = _tree("both", bias=[[0.0], [0.0], [0.0], [1.0], [2.0], [1.0], [3.0]])
    tree = tree.with_parameters(tree.threshold, tree.bias,
                                np.where(np.arange(7)[:, None, None] == 5, tree.weights[3],
                                         tree.weights))
    _, commands = leaf_commands(tree, PENDULUM)
    names = rule_names(commands, PENDULUM)
    text = [", ".join(commands.text(k, PENDULUM.feature_names)) for k in range(4)]
    assert text[0] == text[2] and len(set(text)) == 3
    assert names == (f"{text[0]} (rule 1)", text[1], f"{text[2]} (rule 3)", text[3])
    assert names[1].startswith("torque := 2 ")


# ------------------------------------------------------------------------ the layout
def test_each_split_is_laid_out_in_the_smaller_of_its_two_orders():
    # a leaf on the left: the "<=" side first, the right subtree's rules follow inline
    right = controller_bt(_tree("right"), PENDULUM, _states(_tree("right"))).bt
    c0, c2 = (split_condition(_tree("right"), k, op) for k, op in ((0, "<="), (2, "<=")))
    assert right.root == Selector((Sequence((c0, Action(0))), Sequence((c2, Action(1))),
                                   Action(2)))
    # a leaf on the right: the ">" side first, so the left subtree's rules follow inline
    tree = _tree("left")
    left = controller_bt(tree, PENDULUM, _states(tree)).bt
    assert left.root == Selector((Sequence((split_condition(tree, 0, ">"), Action(2))),
                                  Sequence((split_condition(tree, 1, "<="), Action(0))),
                                  Action(1)))
    # splits on both sides: the first order at a tie; the left subtree nests in a Fallback
    tree = _tree("both")
    both = controller_bt(tree, PENDULUM, _states(tree)).bt
    assert both.root == Selector((
        Sequence((split_condition(tree, 0, "<="),
                  Fallback((Sequence((split_condition(tree, 1, "<="), Action(0))),
                            Action(1))))),
        Sequence((split_condition(tree, 2, "<="), Action(2))), Action(3)))
    assert both.node_count <= 4 * 4 - 3


@settings(max_examples=12, deadline=None)
@given(st.sampled_from(["right", "left", "both"]), st.integers(0, 2 ** 16),
       st.lists(st.sampled_from(list(SPLITS)), min_size=3, max_size=3))
def test_a_controller_bt_sends_exactly_the_trees_command_with_one_rule_per_leaf(shape, seed,
                                                                               splits):
    """Law: on every state checked the BT's command is the tree's, bit for bit; one Action per
    leaf, at most ``4 L - 3`` nodes, a valid tree that reads back as written."""
    tree = _tree(shape, splits=tuple(splits), seed=seed)
    states = _states(tree, seed=seed)
    built = controller_bt(tree, PENDULUM, states)
    x = widen(states)
    assert np.array_equal(built.bt.commands.evaluate(built.bt.decide(x), x), tree.decide(x))
    assert built.states_checked == len(states) and built.disagreements == 0
    with pytest.raises(dataclasses.FrozenInstanceError):  # what the check saw stays as seen
        built.disagreements = 1  # type: ignore[misc]
    assert built.rules == tree.n_leaves and built.bt.node_count <= 4 * tree.n_leaves - 3
    assert built.bt.action_names == rule_names(leaf_commands(tree, PENDULUM)[1], PENDULUM)
    assert BehaviorTree.from_json(built.bt.to_json()) == built.bt


def test_an_oblique_tree_s_bt_decides_its_actions():
    left, right = np.array([1, -1, 3, -1, -1]), np.array([2, -1, 4, -1, -1])
    split = np.zeros((5, 4))
    split[0, 2], split[2, [0, 1, 3]] = 1.0, [0.5, -1.0, 2.0]
    tree = ObliqueArrays(left, right, split, np.array([0.01, 0.0, 0.3, 0.0, 0.0]),
                         np.array([-1, 1, -1, 0, 1]))
    rng = np.random.default_rng(0)
    states = rng.uniform(-0.5, 0.5, size=(400, 4)).astype(np.float32)
    built = controller_bt(tree, CARTPOLE, states)
    assert built.bt.action_names == tuple(CARTPOLE.action_names) and built.bt.commands is None
    assert np.array_equal(built.bt.decide(states), tree.decide(states))
    assert built.rules == 3 and built.states_checked == 400
    assert set(tree.decide(states).tolist()) == {0, 1}


# ------------------------------------------------------------------------- the check
def test_a_bt_sending_another_command_is_refused_counting_the_states(monkeypatch):
    tree = _tree("right")
    states = _states(tree)
    original = synth.leaf_commands

    def off_at_leaf_3(tree_, task):  # the rule of leaf 3 sends 1e-9 more
        order, commands = original(tree_, task)
        values = tuple((v[0] + 1e-9,) if leaf == 3 else v
                       for leaf, v in zip(order, commands.values, strict=True))
        return order, replace(commands, values=values)

    monkeypatch.setattr(synth, "leaf_commands", off_at_leaf_3)
    reach = int((tree.leaf_of(widen(states)) == 3).sum())
    assert 0 < reach < len(states)
    with pytest.raises(ValueError, match=f"sends another command on {reach} of "
                                         f"{len(states)} states; it is not written"):
        controller_bt(tree, PENDULUM, states)


def test_an_oblique_bt_deciding_another_action_is_refused(monkeypatch):
    left, right = np.array([1, -1, -1]), np.array([2, -1, -1])
    split = np.zeros((3, 4))
    split[0, 0] = 1.0
    tree = ObliqueArrays(left, right, split, np.zeros(3), np.array([-1, 0, 1]))
    states = np.array([[-1, 0, 0, 0], [1, 0, 0, 0], [2, 0, 0, 0]], dtype=np.float32)
    assert controller_bt(tree, CARTPOLE, states).disagreements == 0
    original = synth.split_condition
    monkeypatch.setattr(synth, "split_condition", lambda t, node, op: original(
        t.with_parameters(t.threshold + 1.5, t.split), node, op))
    with pytest.raises(ValueError, match="on 1 of 3 states"):
        controller_bt(tree, CARTPOLE, states)


def test_a_rule_sending_nan_agrees_with_the_leaf_sending_nan():
    """The check compares commands bit for bit, NaN with NaN: a leaf whose command is NaN
    (a degenerate fit) is the same command in the BT, not a disagreement."""
    tree = _tree("right", bias=[[0.0], [math.nan], [0.0], [0.5], [1.0]])
    states = _states(tree)
    built = controller_bt(tree, PENDULUM, states)
    x = widen(states)
    sent = built.bt.commands.evaluate(built.bt.decide(x), x)
    assert built.disagreements == 0 and np.isnan(sent).any() and not np.isnan(sent).all()


# ------------------------------------------------------------------- the check's states
def test_the_check_states_are_visited_random_in_the_box_and_both_sides_of_each_axis_test():
    tree = _tree("both", splits=("pair", "axis", "scaled"))
    tree = tree.with_parameters(np.array([0.3, -0.25, 0.7, 0, 0, 0, 0]), tree.bias,
                                tree.weights)  # axis tests below and above 0
    task = replace(PENDULUM, low=(-np.inf, -1.0, -5000.0), high=(np.inf, 1.0, 5000.0))
    visited = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    rows = check_states(tree, task, visited, seed=5, n_random=50)
    assert rows.dtype == np.float32 and rows.shape == (2 + 50 + 3 * 2, 3)
    assert np.array_equal(rows[:2], visited.astype(np.float32))
    want = np.random.default_rng(5).uniform([-10.0, -1.0, -1e3], [10.0, 1.0, 1e3],
                                            size=(50, 3)).astype(np.float32)
    assert np.array_equal(rows[2:52], want)
    edges = rows[52:]
    for k, (node, feature) in enumerate(((1, 0), (2, 1))):  # the axis tests; "pair" has two
        at = np.float32(tree.threshold[node])
        below, above = (np.nextafter(at, np.float32(d)) for d in (-np.inf, np.inf))
        block = edges[3 * k:3 * k + 3]
        assert block[:, feature].tolist() == [below, at, above]
        others = [f for f in range(3) if f != feature]
        assert np.array_equal(block[:, others], np.repeat(rows[:1, others], 3, axis=0))
    defaults = check_states(tree, task, visited)  # 2000 random states, seed 0
    assert defaults.shape == (2 + 2000 + 6, 3) and np.array_equal(
        defaults[2:2002], np.random.default_rng(0).uniform(
            [-10.0, -1.0, -1e3], [10.0, 1.0, 1e3], size=(2000, 3)).astype(np.float32))
    unvisited = check_states(tree, task, np.zeros((0, 3)), seed=5, n_random=50)
    assert unvisited.shape == (56, 3) and np.array_equal(unvisited[:50], want)
    assert np.array_equal(unvisited[50, 1:], want[0, 1:])  # edges next to the first random


# ------------------------------------------------------------------------ rules text
def test_the_rules_read_as_if_elif_else_nested_where_the_bt_nests():
    tree = _tree("both")
    bt = controller_bt(tree, PENDULUM, _states(tree)).bt
    c = [bt.label(split_condition(tree, k, "<=")) for k in range(3)]
    a = bt.action_names
    assert rules_text(bt) == [f"if {c[0]}:", f"    if {c[1]}: {a[0]}", f"    else: {a[1]}",
                              f"elif {c[2]}: {a[2]}", f"else: {a[3]}"]


def test_a_default_alone_always_acts_and_a_sequence_without_tests_is_true():
    def bt(root):
        return BehaviorTree(root, ("x", "y"), ("a", "b", "c"))
    assert rules_text(bt(Selector((Action(1),)))) == ["always: b"]
    assert rules_text(bt(Selector((Sequence((Action(0),)), Action(1))))) == [
        "if true: a", "else: b"]
    assert rules_text(bt(Sequence((Condition(0, "<=", 1.0), Condition(1, ">", 2.0),
                                   Action(2))))) == ["if x <= 1 and y > 2: c"]
    assert rules_text(bt(Selector((Fallback((Sequence((Condition(0, "<=", 1.0), Action(0))),
                                             Action(1))), Action(2))))) == [
        "if true:", "    if x <= 1: a", "    else: b", "else: c"]
    two = Sequence((Condition(0, "<=", 1.0), Action(0), Action(1)))
    assert rules_text(bt(Selector((two, Action(2))))) == [
        "if x <= 1:", "    always: a", "    always: b", "else: c"]
