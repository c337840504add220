"""Imitation-BT synthesis: structure as the paper describes it, exactness proven."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.model import Action, Selector, Sequence
from ibt.synth.imitation import NotEquivalentError, imitation_bt, verify
from ibt.tasks.catalogue import Task, get_task
from tests.conftest import fit_tree

TOY = Task(name="toy", gym_id="none", feature_names=("f0", "f1", "f2", "f3"),
           action_names=("a0", "a1", "a2", "a3"), low=(-1,) * 4, high=(1,) * 4)


def test_structure_root_selector_with_default_last():
    tree, _ = fit_tree(leaves=10)
    result = imitation_bt(tree, TOY)
    root = result.bt.root
    assert isinstance(root, Selector)
    assert root.children[-1] == Action(result.default_action)
    for child in root.children[:-1]:  # one guarded Sequence per non-default action
        assert isinstance(child, Sequence)
        assert isinstance(child.children[-1], Action)
    ks = [rs.k for rs in result.rule_sets]
    assert ks == sorted(ks)
    assert result.default_action == result.rule_sets[-1].action  # the largest k (eq. 14)


@pytest.mark.parametrize("strategy", ["max_complexity", "most_frequent", "smallest_tree"])
def test_every_default_strategy_is_exact(strategy):
    tree, _ = fit_tree(leaves=16, n_actions=4, seed=1)
    result = imitation_bt(tree, TOY, default_strategy=strategy)
    assert verify(result.bt, tree, TOY) > 20_000


def test_smallest_tree_is_never_larger():
    for seed in range(5):
        tree, _ = fit_tree(leaves=16, n_actions=4, seed=seed)
        sizes = {s: imitation_bt(tree, TOY, default_strategy=s).bt.node_count
                 for s in ("max_complexity", "most_frequent", "smallest_tree")}
        assert sizes["smallest_tree"] <= min(sizes.values())


def test_unknown_strategy_is_rejected():
    tree, _ = fit_tree()
    with pytest.raises(ValueError, match="default strategy"):
        imitation_bt(tree, TOY, default_strategy="largest")


def test_verify_catches_a_wrong_tree():
    tree, _ = fit_tree(leaves=10)
    good = imitation_bt(tree, TOY).bt
    root = good.root
    wrong_default = Action((root.children[-1].action + 1) % 3)
    bad = dataclasses.replace(good, root=Selector((*root.children[:-1], wrong_default)))
    with pytest.raises(NotEquivalentError, match="disagrees"):
        verify(bad, tree, TOY)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 5_000), leaves=st.integers(2, 40), n_actions=st.integers(2, 4),
       dont_cares=st.booleans())
def test_bt_decides_as_tree_everywhere(seed, leaves, n_actions, dont_cares):
    tree, _ = fit_tree(leaves=leaves, n_actions=n_actions, seed=seed, n=500)
    result = imitation_bt(tree, TOY, dont_cares=dont_cares, check=False)
    rng = np.random.default_rng(seed)
    states = rng.uniform(-1.5, 1.5, size=(3000, 4)).astype(np.float32)
    assert np.array_equal(result.bt.decide(states), tree.predict(states))
    verify(result.bt, tree, TOY, seed=seed)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-3, 3, width=32), min_size=4, max_size=4))
def test_cartpole_bt_matches_tree_on_hypothesis_states(state):
    tree, _ = fit_tree(leaves=8, n_actions=2, seed=7)
    task = get_task("CartPole-v1")
    bt = imitation_bt(tree, task).bt
    x = np.array([state], dtype=np.float32)
    assert bt.decide(x)[0] == tree.predict(x)[0]
