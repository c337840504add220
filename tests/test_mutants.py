"""Pins of what mutation testing of the core found unguarded: each test fails on a mutant that
survived every other test (the mutant is named in the test's docstring).

* the paper's raw retention, ``100 * mean / expert`` (no other test calls it);
* the verifier's enumeration of a discrete state space, ``arange(low, high + 1)``, and the
  task's sampler of integer states (the last state must be tested and sampled);
* the synthesiser's shape rules: a one-literal term is a bare Condition, a one-term rule puts
  its conditions straight into the action's Sequence;
* the default action's tie-breaks: ``max_complexity`` takes the larger action index among
  rules of equal complexity, ``most_frequent`` the smaller among leaves of equal mass;
* the message for a non-finite value in a single state names the feature and no row.
"""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.executors import NonFiniteObservation, tick
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Selector, Sequence
from ibt.evaluate.rollouts import retention_norm, retention_raw
from ibt.synth.imitation import (
    NotEquivalentError,
    RuleSet,
    assemble,
    imitation_bt,
    verification_states,
    verify,
)
from ibt.synth.rules import Literal, action_template_library
from ibt.tasks.catalogue import get_task

FROZEN = get_task("FrozenLake-v1")


def test_raw_retention_is_the_mean_return_as_a_percentage_of_the_expert_s():
    """Mutants: ``/`` for ``*``, ``*`` for ``/``, ``+`` for ``*``, 10.0 for 100.0."""
    assert retention_raw(50.0, 200.0) == 25.0
    assert retention_raw(-150.0, -100.0) == 150.0  # negative returns: the raw ratio, unshifted
    assert retention_raw(3.0, 4.0) == 75.0
    assert retention_norm(50.0, 200.0, 0.0) == retention_raw(50.0, 200.0)


def _split_at_seven() -> DecisionTreeClassifier:
    states = np.arange(16, dtype=np.float32)[:, None]
    return DecisionTreeClassifier(random_state=0).fit(states, (states[:, 0] > 7).astype(int))


def test_the_verifier_enumerates_every_discrete_state_the_last_included():
    """Mutant: ``arange(low, high)`` (state 15 of FrozenLake never checked)."""
    tree = _split_at_seven()
    states = verification_states(tree, FROZEN, n_random=0)
    assert set(range(16)) <= set(states[:, 0].tolist())
    # a BT that differs from its tree on the last state only (15 -> action 2, the tree says 1)
    differs_at_15 = BehaviorTree(Selector((
        Sequence((Condition(0, ">", 14.5), Action(2))),
        Sequence((Condition(0, "<=", 7.5), Action(0))),
        Action(1))), FROZEN.feature_names, FROZEN.action_names)
    with pytest.raises(NotEquivalentError, match=r"\[15\.0\] -> BT 2, tree 1"):
        verify(differs_at_15, tree, FROZEN, n_random=0)
    assert verify(imitation_bt(tree, FROZEN).bt, tree, FROZEN, n_random=0) == len(states)


def test_integer_states_are_sampled_up_to_the_last():
    """Mutant: ``rng.integers(low, high)`` in :meth:`Task.sample_features` (never state 15)."""
    sampled = FROZEN.sample_features(2000, np.random.default_rng(0))
    assert set(sampled[:, 0].tolist()) == set(map(float, range(16)))


def _lit(feature: int, op: str, threshold: float) -> Literal:
    return Literal(feature, threshold, op == "<=")


def test_one_literal_terms_are_bare_conditions_and_one_term_rules_are_flat():
    """Mutants: ``len(term) == 1`` changed (``!= 1``, ``>= 1``, ``== 2`` or the branch removed:
    a Sequence of one Condition, or literals lost) and ``len(rs.terms) == 1`` likewise."""
    two_terms = RuleSet(0, ((_lit(0, "<=", 1.0),), (_lit(1, ">", 2.0), _lit(2, "<=", 3.0))))
    one_term = RuleSet(1, ((_lit(0, ">", 1.0), _lit(1, "<=", 2.0)),))
    one_literal = RuleSet(2, ((_lit(3, ">", 4.0),),))
    root = assemble([one_literal, one_term, two_terms], default=3)
    assert root == Selector((
        Sequence((Condition(3, ">", 4.0), Action(2))),
        Sequence((Condition(0, ">", 1.0), Condition(1, "<=", 2.0), Action(1))),
        Sequence((Fallback((Condition(0, "<=", 1.0),
                            Sequence((Condition(1, ">", 2.0), Condition(2, "<=", 3.0))))),
                  Action(0))),
        Action(3)))


def _two_leaves(left_action: int, right_action: int) -> DecisionTreeClassifier:
    """``x <= 0 -> left_action`` and ``x > 0 -> right_action``: one literal each, one sample
    each (equal complexity and equal mass: every tie-break decides)."""
    x = np.array([[-1.0], [1.0]], dtype=np.float32)
    return DecisionTreeClassifier(random_state=0).fit(x, [left_action, right_action])


@pytest.mark.parametrize(("left", "right"), [(1, 0), (0, 1), (3, 1)])
def test_the_default_action_ties_break_as_documented(left, right):
    """Mutants: the sort key ``(k, action)`` of the rule sets as ``(k,)`` or ``(k, -action)``
    (max_complexity then takes the smaller index), and ``(mass, -a)`` in ``_most_frequent`` as
    ``(mass, a)`` (most_frequent then takes the larger index). The sort key ``(k,)`` alone is
    an equivalent mutant while the ATL lists actions in increasing order (a stable sort keeps
    it), so that order is pinned too (mutant: ``dict(sorted(atl.items()))`` as ``atl``)."""
    tree = _two_leaves(left, right)
    largest = imitation_bt(tree, FROZEN, default_strategy="max_complexity")
    assert [rs.k for rs in largest.rule_sets] == [1, 1]
    assert largest.default_action == max(left, right)
    frequent = imitation_bt(tree, FROZEN, default_strategy="most_frequent")
    assert frequent.default_action == min(left, right)
    assert largest.bt.root.children[-1] == Action(max(left, right))
    assert list(action_template_library(tree)) == sorted({left, right})  # leaves in action order


def test_a_non_finite_value_in_one_state_names_its_feature_and_no_row():
    """Mutant: ``bad.size > 1`` as ``>= 1`` (one state then reads "of row 2") or ``bad[-1]``
    as ``bad[0]`` (a batch then names the row as the feature)."""
    bt = BehaviorTree(Selector((Sequence((Condition(2, "<=", 0.0), Action(0))), Action(1))),
                      ("a", "b", "c"), ("left", "right"))
    with pytest.raises(NonFiniteObservation, match=r"holds nan at feature 2 \(after"):
        tick(bt, np.array([0.0, 0.0, np.nan]))
    with pytest.raises(NonFiniteObservation, match=r"holds inf at feature 1 \(after"):
        tick(bt, np.array([0.0, 1e39, 0.0]))  # beyond float32: infinite after the cast
    batch = np.zeros((3, 3))
    batch[0, 2] = np.nan
    with pytest.raises(NonFiniteObservation, match=r"at feature 2 of row 0 \(after"):
        bt.decide(batch)
