"""The project's central claim, that every Imitation-BT decides exactly as its tree, rests on
the verifier; these laws pin the verifier itself and the choices the synthesiser makes:

* the verification states hold a witness inside **every leaf** of the tree (the bounds start
  unbounded: a leaf left of a negative threshold gets one too);
* a BT that differs from its tree inside **one leaf only** is refused;
* ``imitation_bt(..., check=True)`` (the default) really verifies: a wrong assembly is
  refused, ``check=False`` returns it;
* the default action's strategies: ``most_frequent`` weighs leaves by their training samples,
  ``smallest_tree`` breaks a tie in size towards the most complex rule; ``rules_frame`` marks
  the default's row; don't-cares are used only when asked for.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import Action, BehaviorTree, Condition, Selector, Sequence, iterate
from ibt.synth import imitation
from ibt.synth.imitation import (
    NotEquivalentError,
    assemble,
    imitation_bt,
    minimised_rule_sets,
    rules_frame,
    verification_states,
    verify,
)
from ibt.synth.rules import leaf_paths
from ibt.tasks.catalogue import get_task
from tests.conftest import fit_tree

# four unbounded features, as fit_tree's trees have, and four actions
CARTPOLE = replace(get_task("CartPole-v1"), action_names=("a0", "a1", "a2", "a3"))
SLOW_OK = settings(max_examples=15, deadline=None,
                   suppress_health_check=[HealthCheck.too_slow])


def _leaf_of_every_state(tree: DecisionTreeClassifier, states: np.ndarray) -> set[int]:
    return set(tree.apply(states.astype(np.float32)).tolist())


def _all_leaves(tree: DecisionTreeClassifier) -> set[int]:
    return set(np.flatnonzero(tree.tree_.children_left == -1).tolist())


@SLOW_OK
@given(seed=st.integers(0, 50), leaves=st.integers(2, 14), n_actions=st.integers(2, 4),
       dont_cares=st.booleans())
def test_a_bt_decides_as_its_tree_on_witness_states_of_every_leaf(seed, leaves, n_actions,
                                                                 dont_cares):
    """Mutants: the witnesses' bounds starting at 0 (or +inf) instead of -inf (leaves left of
    a negative threshold get no witness)."""
    tree, _ = fit_tree(leaves=leaves, n_actions=n_actions, seed=seed, n=400)
    states = verification_states(tree, CARTPOLE, n_random=0)
    assert _leaf_of_every_state(tree, states) == _all_leaves(tree)
    bt = imitation_bt(tree, CARTPOLE, dont_cares=dont_cares, check=False).bt
    assert bt.decide(states).tolist() == tree.predict(states).tolist()


@SLOW_OK
@given(seed=st.integers(0, 50), leaves=st.integers(2, 14), pick=st.integers(0, 1000))
def test_a_bt_that_differs_from_its_tree_in_one_leaf_only_is_refused(seed, leaves, pick):
    """Mutants: a witness missing from any leaf, or a verifier that passes a disagreement."""
    tree, _ = fit_tree(leaves=leaves, n_actions=3, seed=seed, n=400)
    right = imitation_bt(tree, CARTPOLE).bt
    path = leaf_paths(tree)[pick % tree.get_n_leaves()]
    other = (path.action + 1) % 3
    inside = tuple(Condition(lit.feature, lit.op, lit.threshold) for lit in path.term)
    wrong = BehaviorTree(Selector((Sequence((*inside, Action(other))), right.root)),
                         right.feature_names, right.action_names)
    with pytest.raises(NotEquivalentError, match=r"disagrees with its tree on \d+ of \d+ states"):
        verify(wrong, tree, CARTPOLE, n_random=0)
    n_witnesses = len(verification_states(tree, CARTPOLE, n_random=0))
    assert verify(right, tree, CARTPOLE, n_random=0) == n_witnesses
    assert verify(right, tree, CARTPOLE, n_random=25) == n_witnesses + 25


def test_check_true_really_verifies(monkeypatch):
    """Mutants: ``if check`` inverted or its ``verify`` call skipped, and the default
    ``check=True`` flipped to False."""
    tree, _ = fit_tree(leaves=8, n_actions=3, seed=1, n=400)
    real = imitation.assemble

    def one_rule_lost(rule_sets, default):  # a wrong BT: one action's region goes to the default
        lost = next(rs.action for rs in rule_sets if rs.action != default)
        return real([rs for rs in rule_sets if rs.action != lost], default)

    monkeypatch.setattr(imitation, "assemble", one_rule_lost)
    with pytest.raises(NotEquivalentError):
        imitation_bt(tree, CARTPOLE)
    with pytest.raises(NotEquivalentError):
        imitation_bt(tree, CARTPOLE, check=True)
    unchecked = imitation_bt(tree, CARTPOLE, check=False)
    with pytest.raises(NotEquivalentError):
        verify(unchecked.bt, tree, CARTPOLE)


def test_check_verifies_with_the_given_seed(monkeypatch):
    """Mutant: ``rng_seed`` not passed on to :func:`verify`."""
    tree, _ = fit_tree(leaves=6, n_actions=2, seed=2, n=300)
    seen = []
    monkeypatch.setattr(imitation, "verify", lambda bt, tree, task, *, seed: seen.append(seed))
    imitation_bt(tree, CARTPOLE, rng_seed=7)
    imitation_bt(tree, CARTPOLE, check=False, rng_seed=8)
    assert seen == [7]


def _three_regions() -> DecisionTreeClassifier:
    """Action 1 where ``x0 <= 0 or x1 <= 0`` (two one-literal terms, k = 2), action 2 on
    ``x0 > 0, x1 > 0, x2 <= 0`` and action 0 on ``x0 > 0, x1 > 0, x2 > 0`` (k = 3 each): every
    default gives a BT of 12 nodes."""
    corners = np.array([[a, b, c, 0.0] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)],
                       dtype=np.float32)
    labels = [1 if a < 0 or b < 0 else (2 if c < 0 else 0) for a, b, c, _ in corners]
    return DecisionTreeClassifier(random_state=0).fit(corners, labels)


def test_smallest_tree_breaks_a_tie_in_size_towards_the_most_complex_rule():
    """Mutants: the tie-break ``-_k_of`` as ``+_k_of`` or dropped (the simpler rule of action
    1 would become the default)."""
    tree = _three_regions()
    sets = minimised_rule_sets(tree)
    assert {rs.action: rs.k for rs in sets} == {1: 2, 0: 3, 2: 3}
    assert {a: sum(1 for _ in iterate(assemble(sets, a))) for a in (0, 1, 2)} == {
        0: 12, 1: 12, 2: 12}
    result = imitation_bt(tree, CARTPOLE, default_strategy="smallest_tree")
    assert result.bt.node_count == 12
    assert result.default_action == 0  # k = 3, the smaller index of the two
    assert result.default_strategy == "smallest_tree"


def test_most_frequent_weighs_leaves_by_their_training_samples():
    """Mutant: ``mass[a] + path.samples`` counting leaves (action 0 has two leaves of one
    sample each, action 1 one leaf of five samples)."""
    x = np.array([[0.0], [2.0], [1.0], [1.0], [1.0], [1.0], [1.0]], dtype=np.float32)
    tree = DecisionTreeClassifier(random_state=0).fit(np.hstack([x, np.zeros((7, 3))]),
                                                      [0, 0, 1, 1, 1, 1, 1])
    assert sorted((p.action, p.samples) for p in leaf_paths(tree)) == [(0, 1), (0, 1), (1, 5)]
    assert imitation_bt(tree, CARTPOLE, default_strategy="most_frequent").default_action == 1


def test_rules_frame_marks_the_default_s_row_and_only_it():
    """Mutants: the ``default`` column as ``!=``, the k or terms columns miscounted."""
    tree = _three_regions()
    result = imitation_bt(tree, CARTPOLE, default_strategy="max_complexity")
    frame = rules_frame(result)
    names = CARTPOLE.action_names
    assert frame["default"].tolist() == [rs.action == result.default_action
                                         for rs in result.rule_sets]
    assert frame["default"].sum() == 1
    assert frame.loc[frame["default"], "action"].item() == names[result.default_action]
    assert frame["k"].tolist() == [2, 3, 3] and frame["terms"].tolist() == [2, 1, 1]
    feature = CARTPOLE.feature_names
    assert frame["rule"].iloc[0] == f"({feature[0]} <= 0) OR ({feature[1]} <= 0)"


def test_dont_cares_are_used_when_asked_and_only_then():
    """Mutants: ``dont_cares`` inverted or dropped on its way to Espresso."""
    tree, _ = fit_tree(leaves=12, seed=4)
    plain = imitation_bt(tree, CARTPOLE)
    with_dc = imitation_bt(tree, CARTPOLE, dont_cares=True)
    total = {name: sum(rs.k for rs in r.rule_sets)
             for name, r in (("plain", plain), ("dont_cares", with_dc))}
    assert total == {"plain": 26, "dont_cares": 20}
    assert plain.rule_sets == tuple(minimised_rule_sets(tree))
    assert with_dc.rule_sets == tuple(minimised_rule_sets(tree, dont_cares=True))
