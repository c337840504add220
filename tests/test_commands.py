"""Named commands (ibt.synth.commands) on small regression trees of hand-made labels: the leaf
table, the merge of leaves into rounded commands, the classifier over command ids, the choice of
``k`` by return, and a BT with commands as a policy. Quick: no expert, no distillation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeRegressor

from ibt.bt.model import Action, BehaviorTree, Commands, Condition, Fallback, Sequence
from ibt.synth.commands import (
    DECIMALS,
    CommandBTPolicy,
    _number,
    bt_actions,
    choose_commands,
    command_name,
    command_task,
    command_tree,
    leaf_table,
    merge_leaves,
    to_classifier,
    with_commands,
)
from ibt.tasks.catalogue import get_task

PENDULUM = get_task("Pendulum-v1")  # one dimension, torque in [-2, 2] N m
LANDER = get_task("LunarLanderContinuous-v3")  # two dimensions in [-1, 1]


def _tree(task, labels, *, leaves: int, n: int = 2000, seed: int = 0) -> DecisionTreeRegressor:
    x = task.sample_features(n, np.random.default_rng(seed))
    return DecisionTreeRegressor(max_leaf_nodes=leaves, random_state=0).fit(x, labels(x))


def _smooth(x: np.ndarray) -> np.ndarray:
    """Two-dimensional labels inside LunarLander's box that vary with two features."""
    return np.clip(np.stack([np.tanh(x[:, 0] * 2 + x[:, 2]), 0.7 * np.sin(3 * x[:, 1])], 1),
                   -1, 1)


@pytest.fixture(scope="module")
def lander_tree() -> DecisionTreeRegressor:
    return _tree(LANDER, _smooth, leaves=10)


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_a_number_is_its_value_to_two_decimals_without_trailing_zeros(value):
    text = _number(value)
    assert float(text) == float(f"{value:.{DECIMALS}f}")
    assert text != "-0" and not text.endswith(".") and not ("." in text and text.endswith("0"))
    assert len(text.partition(".")[2]) <= DECIMALS


def test_command_names_name_each_dimension_with_its_unit():
    assert command_name(PENDULUM, np.array([-0.0])) == "torque 0 N m"
    assert command_name(PENDULUM, np.array([1.5])) == "torque 1.5 N m"
    assert command_name(LANDER, np.array([0.8, -0.35])) == "main_engine 0.8, side_engine -0.35"
    unitless = command_task(PENDULUM, ("a",))
    assert not unitless.continuous and unitless.action_names == ("a",)
    assert unitless.action_units == () and unitless.feature_names == PENDULUM.feature_names


def test_the_leaf_table_holds_every_leaf_its_value_and_its_samples(lander_tree):
    nodes, values, visits = leaf_table(lander_tree)
    t = lander_tree.tree_
    assert list(nodes) == [i for i in range(t.node_count) if t.children_left[i] == -1]
    assert values.shape == (len(nodes), 2) and values.dtype == np.float64
    x = LANDER.sample_features(2000, np.random.default_rng(0))  # the training rows
    reached = lander_tree.apply(x)
    for node, value, count in zip(nodes, values, visits, strict=True):
        assert count == np.sum(reached == node)
        assert np.allclose(value, _smooth(x[reached == node]).mean(axis=0))


@pytest.mark.parametrize("k", [1, 2, 3, 5, 10, 20])
def test_merged_commands_are_the_rounded_weighted_means_of_their_leaves(lander_tree, k):
    _, values, visits = leaf_table(lander_tree)
    leaf_ids, table = merge_leaves(lander_tree, LANDER, k)
    assert 1 <= len(table) <= min(k, len(values)) and table.shape[1] == 2
    # numbered by first use: each id appears first right after the ids below it
    assert list(dict.fromkeys(leaf_ids)) == list(range(len(table)))
    assert len({row.tobytes() for row in table}) == len(table)  # equal commands are one
    assert np.array_equal(table, np.round(table, DECIMALS))
    LANDER.check_action(table)
    for c in range(len(table)):
        mine = leaf_ids == c
        mean = np.average(values[mine], axis=0, weights=visits[mine])
        assert np.abs(table[c] - mean).max() <= 0.5 * 10 ** -DECIMALS + 1e-9
    if k >= len(values):  # every leaf its own command: only the rounding
        assert np.array_equal(table[leaf_ids], np.round(values, DECIMALS))


def test_a_centre_outside_the_box_is_clipped_to_it():
    tree = _tree(PENDULUM, lambda x: np.where(x[:, 0] > 0, 2.0, -2.0), leaves=2)
    tree.tree_.value[tree.tree_.children_left == -1] *= 1.01  # past both bounds, even rounded
    _, table = merge_leaves(tree, PENDULUM, 2)
    assert sorted(table[:, 0]) == [-2.0, 2.0]


def test_the_classifier_keeps_the_splits_and_holds_the_leaves_shares(lander_tree):
    _, _, visits = leaf_table(lander_tree)
    leaf_ids, table = merge_leaves(lander_tree, LANDER, 3)
    clf = to_classifier(lander_tree, leaf_ids, len(table))
    assert list(clf.classes_) == list(range(len(table))) and clf.n_classes_ == len(table)
    x = LANDER.sample_features(3000, np.random.default_rng(5))
    nodes = list(leaf_table(lander_tree)[0])
    expected = leaf_ids[[nodes.index(n) for n in lander_tree.apply(x)]]
    assert np.array_equal(clf.predict(x), expected)
    assert np.array_equal(clf.apply(x), lander_tree.apply(x))
    value = clf.tree_.value[:, 0, :]
    assert np.allclose(value.sum(axis=1), 1.0)
    # every node holds the sample shares of the commands of the leaves below it
    assert np.allclose(value[0], np.bincount(leaf_ids, weights=visits) / visits.sum())
    t = lander_tree.tree_
    for node in np.flatnonzero(t.children_left != -1):
        left, right = t.children_left[node], t.children_right[node]
        w_left, w_right = t.weighted_n_node_samples[left], t.weighted_n_node_samples[right]
        mix = (w_left * value[left] + w_right * value[right]) / (w_left + w_right)
        assert np.allclose(value[node], mix)


@pytest.mark.parametrize("k", [1, 2, 4])
def test_a_command_tree_sends_its_commands_and_names_them(lander_tree, k):
    ct = command_tree(lander_tree, LANDER, k)
    assert ct.n_commands == len(ct.commands.values) <= k
    assert ct.commands.dimensions == LANDER.action_names
    assert ct.commands.units == LANDER.action_units
    assert ct.task.action_names == tuple(command_name(LANDER, np.array(v))
                                         for v in ct.commands.values)
    x = LANDER.sample_features(1000, np.random.default_rng(k))
    sent = ct.actions(x)
    assert sent.shape == (len(x), 2)
    assert np.array_equal(sent, ct.commands.array()[ct.tree.predict(x)])
    obs = x.astype(np.float32)
    assert np.array_equal(ct.policy(LANDER)(obs), sent)


def test_a_command_tree_needs_a_box_task_and_at_least_one_command(lander_tree):
    with pytest.raises(ValueError, match="discrete actions"):
        command_tree(lander_tree, get_task("CartPole-v1"), 2)
    with pytest.raises(ValueError, match="at least one command"):
        command_tree(lander_tree, LANDER, 0)
    assert command_tree(lander_tree, LANDER, 1).n_commands == 1


@pytest.fixture(scope="module")
def three_regions() -> DecisionTreeRegressor:
    """Pendulum's torque along its angular velocity (pumping energy) but braking when fast:
    three leaves, two exact values, so two commands send exactly the tree's own actions."""
    tree = _tree(PENDULUM, lambda x: np.where(x[:, 2] < -4, 1.5, np.where(x[:, 2] < 0, -1.5, 1.5)),
                 leaves=3)
    assert tree.get_n_leaves() == 3
    return tree


def _within(rows, bound):
    """The law of the choice: every k before the last measured loses more than ``bound``."""
    return all(r["loss"] > bound for r in rows[:-1])


def test_the_smallest_k_within_the_tolerance_is_chosen(three_regions):
    seeds = [0, 1]
    chosen, rows = choose_commands(three_regions, PENDULUM, seeds, scale=1.0, tolerance=0.0)
    assert [r["k"] for r in rows] == list(range(1, len(rows) + 1)) and _within(rows, 0.0)
    for r in rows:
        assert r["loss"] == r["tree_return"] - r["mean_return"]
        assert r["commands"] <= r["k"] and r["tree_return"] == rows[0]["tree_return"]
    # k = 2 sends exactly the tree's actions: a loss of 0, within a tolerance of 0
    assert rows[-1]["loss"] <= 0 and len(rows) <= 2 and chosen.n_commands == rows[-1]["commands"]
    # a tolerance of the whole loss of k = 1 keeps k = 1, whatever the sign of the scale
    for scale in (abs(rows[0]["loss"]), -abs(rows[0]["loss"])):
        chosen, again = choose_commands(three_regions, PENDULUM, seeds, scale=scale,
                                        tolerance=1.0)
        assert [r["k"] for r in again] == [1] and chosen.n_commands == 1


def test_with_no_k_within_the_tolerance_every_leaf_is_its_own_command(three_regions):
    chosen, rows = choose_commands(three_regions, PENDULUM, [0], scale=1.0, tolerance=-1e9)
    assert [r["k"] for r in rows] == [1, 2, 3]
    assert chosen.n_commands == 2  # three leaves, two distinct rounded values


def _bt_with_commands(values, terms=None) -> BehaviorTree:
    root = Fallback((Sequence((Condition(0, "<=", 0.0), Action(0))), Action(1)))
    bt = BehaviorTree(root, PENDULUM.feature_names, ("low", "high"))
    return with_commands(bt, Commands(("torque",), ("N m",), values, terms))


def test_a_bt_with_commands_sends_the_command_of_its_decision():
    bt = _bt_with_commands(((-1.0,), (0.5,)))
    assert bt.commands.values == ((-1.0,), (0.5,))
    x = np.array([[-0.5, 0, 0], [0.5, 0, 0]], dtype=np.float32)
    assert bt_actions(bt, x).tolist() == [[-1.0], [0.5]]
    policy = CommandBTPolicy(PENDULUM, bt)
    assert policy.act(x).tolist() == [[-1.0], [0.5]]
    with pytest.raises(ValueError, match="discrete actions"):
        bt_actions(with_commands(bt, None), x)


def test_a_linear_command_adds_its_terms_on_the_widened_observation():
    bt = _bt_with_commands(((0.0,), (0.25,)), (((),), (((2, 0.5),),)))
    assert bt.commands.linear
    x = np.array([[-0.5, 0, 1.0], [0.5, 0, 0.1]], dtype=np.float32)
    sent = bt_actions(bt, x)
    assert sent.dtype == np.float32
    assert sent.tolist() == [[0.0], [np.float32(0.25 + 0.5 * float(np.float32(0.1)))]]
    CommandBTPolicy(PENDULUM, _bt_with_commands(((0.0,), (9.0,)), (((),), (((2, 0.5),),))))


def test_a_command_bt_policy_refuses_another_task_and_commands_outside_the_box():
    bt = _bt_with_commands(((-1.0,), (0.5,)))
    with pytest.raises(ValueError, match="Box action space"):
        CommandBTPolicy(get_task("CartPole-v1"), bt)
    with pytest.raises(ValueError, match="Box action space"):
        CommandBTPolicy(PENDULUM, with_commands(bt, None))
    with pytest.raises(ValueError, match="pass the task the BT was made for"):
        CommandBTPolicy(get_task("MountainCarContinuous-v0"), bt)
    with pytest.raises(ValueError, match="outside"):
        CommandBTPolicy(PENDULUM, _bt_with_commands(((-1.0,), (2.5,))))


MOUNTAIN_CAR = get_task("MountainCarContinuous-v0")  # one dimension, force in [-1, 1]


@pytest.fixture(scope="module")
def pumping() -> DecisionTreeRegressor:
    """MountainCarContinuous's force along the velocity, which reaches the flag (about 89 on
    seed 0), and full force in a corner never reached: three leaves, two exact values. One
    command (the leaves' mean force, near 0) never reaches the flag: k = 1 loses about 89,
    k = 2 sends exactly the tree's actions."""
    tree = _tree(MOUNTAIN_CAR, lambda x: np.where(x[:, 0] < -1.1, 1.0,
                                                  np.where(x[:, 1] < 0, -1.0, 1.0)), leaves=3)
    assert tree.get_n_leaves() == 3
    return tree


def _ks(tree, **kwargs) -> list[int]:
    chosen, rows = choose_commands(tree, MOUNTAIN_CAR, [0], **kwargs)
    assert chosen.n_commands == rows[-1]["commands"]
    return [r["k"] for r in rows]


def test_a_k_is_kept_where_its_loss_is_within_tolerance_times_the_scale(pumping):
    _, rows = choose_commands(pumping, MOUNTAIN_CAR, [0], scale=1.0, tolerance=-1e9)
    assert [(r["k"], r["commands"]) for r in rows] == [(1, 1), (2, 2), (3, 2)]
    assert 80 < rows[0]["loss"] < 100 and rows[1]["loss"] == rows[2]["loss"] == 0.0
    for r in rows:
        assert r["loss"] == r["tree_return"] - r["mean_return"]
    assert _ks(pumping, scale=1.0, tolerance=0.5) == [1, 2]  # a loss of 89 is not within 0.5
    assert _ks(pumping, scale=-100.0, tolerance=0.9) == [1]  # 89 is within 0.9 x |-100|
    assert _ks(pumping, scale=100.0, tolerance=0.8) == [1, 2]  # not within 0.8 x 100


def test_the_default_tolerance_is_one_percent_of_the_scale(pumping):
    assert _ks(pumping, scale=10_000.0) == [1]  # 89 is within 1 % of 10,000
    assert _ks(pumping, scale=5_000.0) == [1, 2]  # not within 1 % of 5,000


def test_a_task_without_units_names_its_commands_by_value_alone(lander_tree):
    bare = replace(LANDER, action_units=())
    assert command_name(bare, np.array([0.8, -0.35])) == "main_engine 0.8, side_engine -0.35"
    ct = command_tree(lander_tree, bare, 2)
    assert ct.commands.units == ("", "")
    assert ct.task.action_names == tuple(command_name(LANDER, np.array(v))
                                         for v in ct.commands.values)


def test_leaves_are_merged_in_units_of_each_dimensions_box_span():
    """A first dimension of span 2 and a second of span 20: leaves 1.8 apart in the first are
    farther apart, in spans, than leaves 3 apart in the second, so k = 2 splits the first."""
    task = replace(LANDER, action_low=(-1.0, -10.0), action_high=(1.0, 10.0))
    tree = _tree(task, lambda x: np.stack([np.where(x[:, 0] > 0, 0.9, -0.9),
                                           np.where(x[:, 1] > 0, 3.0, 0.0)], 1), leaves=4)
    _, values, _ = leaf_table(tree)
    assert sorted(map(tuple, np.round(values, 6))) == [(-0.9, 0.0), (-0.9, 3.0), (0.9, 0.0),
                                                      (0.9, 3.0)]
    leaf_ids, table = merge_leaves(tree, task, 2)
    assert sorted(table[:, 0]) == [-0.9, 0.9]
    for c in range(2):
        assert len(set(np.sign(values[leaf_ids == c, 0]))) == 1
