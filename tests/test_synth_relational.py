"""The relational route of synthesis (:mod:`ibt.synth.relational`) on small relational trees,
in seconds: the augmented view decides as its tree, a rewritten BT decides in observed space as
it did on augmented rows, the route hands a synthesiser the augmented view and task and
verifies what comes back (with its seed), and the verifier's states are what it says they are.
The synthesisers themselves on relational trees are :mod:`tests.test_relational_bt`'s."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.executors import decide_batch
from ibt.bt.linear import FeatureMap, LinearForm, exact_threshold
from ibt.bt.model import (
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Node,
    Selector,
    Sequence,
)
from ibt.bt.polytope import satisfies
from ibt.distill.relational import RelationalTreeClassifier
from ibt.synth.imitation import NotEquivalentError, Synthesis
from ibt.synth.relational import (
    augmented_view,
    is_relational,
    path_tests,
    rewrite,
    synthesise,
    verification_states,
    verify_relational,
)
from ibt.tasks.catalogue import Task
from tests.fixtures.relational_line import LINE
from tests.fixtures.toy_synthesiser import tree_shaped_bt

FORMS = (LinearForm(0, 2, 1.0, -1.0), LinearForm(0, 1, 0.5, 1.0))  # x - target, x/2 + vx
FMAP = FeatureMap(3, FORMS)


def fit(seed: int = 0, leaves: int = 8, n: int = 600) -> RelationalTreeClassifier:
    """A relational tree on :data:`FMAP` whose labels follow both forms (so it splits on
    derived columns and on observed ones)."""
    rng = np.random.default_rng(seed)
    x = LINE.sample_features(n, rng)
    z = x.astype(np.float64)
    score = FORMS[0].value(z) + 0.4 * np.sign(FORMS[1].value(z)) + 0.3 * np.sin(3 * z[:, 1])
    y = np.digitize(score, np.quantile(score, [1 / 3, 2 / 3]))
    return RelationalTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit_relational(
        x, y, FMAP)


TREE = fit()
STATES = LINE.sample_features(2000, np.random.default_rng(1)).astype(np.float32)


def correct_bt(tree: RelationalTreeClassifier) -> BehaviorTree:
    """An observed-space BT that decides as ``tree``: its augmented tree, split by split,
    rewritten (the route's own rewriting, as a synthesiser's result is)."""
    wide = tree_shaped_bt(augmented_view(tree), LINE).bt
    return BehaviorTree(rewrite(wide.root, FMAP), LINE.feature_names, LINE.action_names)


def point_box(state: np.ndarray) -> tuple[Node, ...]:
    """Conditions that hold on the float32 ``state`` and on no other float32 state."""
    out: list[Node] = []
    for f, v in enumerate(np.asarray(state, dtype=np.float32)):
        out += [Condition(f, "<=", float(v)),
                Condition(f, ">", float(np.nextafter(v, np.float32(-np.inf))))]
    return tuple(out)


def wrong_at(bt: BehaviorTree, state: np.ndarray, tree: RelationalTreeClassifier
             ) -> BehaviorTree:
    """``bt``, but deciding another action on exactly ``state``."""
    other = (int(tree.predict(state[None])[0]) + 1) % LINE.n_actions
    root = Selector((Sequence((*point_box(state), Action(other))), bt.root))
    return BehaviorTree(root, bt.feature_names, bt.action_names)


# ------------------------------------------------------------------ the augmented view
def test_a_relational_tree_is_relational_and_its_view_and_a_plain_tree_are_not():
    plain = DecisionTreeClassifier(max_leaf_nodes=4, random_state=0).fit(
        STATES, (STATES[:, 0] > 0).astype(int))
    assert is_relational(TREE)
    assert not is_relational(augmented_view(TREE)) and not is_relational(plain)


def test_the_augmented_view_is_a_plain_tree_deciding_as_the_relational_one():
    view = augmented_view(TREE)
    assert type(view) is DecisionTreeClassifier and view.tree_ is TREE.tree_
    assert not hasattr(view, "feature_map_")
    assert np.array_equal(view.predict(FMAP.augment(STATES)), TREE.predict(STATES))


# ------------------------------------------------------------------------ rewriting
def test_rewriting_names_derived_columns_as_forms_with_exact_thresholds_and_keeps_the_rest():
    """Every kind of node keeps its kind and its place; an observed column's condition is
    kept as it is; a derived column's becomes its form with the exact threshold."""
    t = 0.1  # not a float32: the exact threshold differs from it
    assert exact_threshold(t) != t
    wide = Selector((
        Sequence((Condition(3, "<=", t), Inverter(Condition(4, ">", -t)), Action(0))),
        Fallback((Condition(1, ">", t), Inverter(Action(2)))),
        Action(1)))
    assert rewrite(wide, FMAP) == Selector((
        Sequence((Condition.relational(FORMS[0], "<=", exact_threshold(t)),
                  Inverter(Condition.relational(FORMS[1], ">", exact_threshold(-t))),
                  Action(0))),
        Fallback((Condition(1, ">", t), Inverter(Action(2)))),
        Action(1)))
    assert type(rewrite(Fallback((Action(0),)), FMAP)) is Fallback


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 1000), leaves=st.integers(2, 12))
def test_a_rewritten_bt_decides_in_observed_space_as_it_did_on_augmented_rows(seed, leaves):
    """Law: for every state, boundaries included, the rewritten BT on the observed row decides
    as the BT on its augmented row (the double ``z <= T`` is the float32 ``z <= t``)."""
    tree = fit(seed, leaves)
    wide = tree_shaped_bt(augmented_view(tree), LINE).bt.root
    states = np.concatenate([verification_states(tree, LINE, n_random=200, seed=seed).states,
                             STATES[:200]])
    assert np.array_equal(decide_batch(rewrite(wide, FMAP), states),
                          decide_batch(wide, FMAP.augment(states).astype(np.float32)))


# ---------------------------------------------------------------------------- the route
def test_the_route_hands_a_synthesiser_the_augmented_view_and_task_and_rewrites_its_bt():
    seen = {}

    def spy(tree, task, **options):
        seen.update(tree=tree, task=task, options=options)
        return tree_shaped_bt(tree, task)

    discrete = Task(name="grid", gym_id="none", feature_names=LINE.feature_names,
                    action_names=LINE.action_names, low=LINE.low, high=LINE.high,
                    discrete_state=True, integer_features=True)
    result = synthesise(spy, TREE, discrete, check=False, rng_seed=3)
    assert not is_relational(seen["tree"]) and seen["tree"].tree_ is TREE.tree_
    assert seen["task"].n_features == FMAP.width
    assert not seen["task"].discrete_state and not seen["task"].integer_features
    assert seen["options"] == {"check": False, "rng_seed": 3}
    assert result.feature_map == FMAP and result.bt.feature_names == LINE.feature_names
    assert result.bt.relational_count > 0
    assert np.array_equal(result.bt.decide(STATES), TREE.predict(STATES))


def test_the_route_verifies_unless_told_not_to():
    def constant(tree, task, **options):
        return Synthesis(BehaviorTree(Selector((Action(0),)), task.feature_names,
                                      task.action_names), "constant", 0, None, ())

    with pytest.raises(NotEquivalentError, match="relational tree"):
        synthesise(constant, TREE, LINE)
    assert synthesise(constant, TREE, LINE, check=False).bt.root == Selector((Action(0),))


def test_the_route_verifies_with_its_rng_seed_zero_by_default():
    """A BT wrong on one random state of seed 1's draw only passes the route's check by
    default (seed 0) and fails it with ``rng_seed=1``."""
    odd = LINE.sample_features(20_000, np.random.default_rng(1)).astype(np.float32)[7]
    wrong = wrong_at(correct_bt(TREE), odd, TREE)

    def returns_wrong(tree, task, **options):
        return Synthesis(wrong, "wrong", None, None, ())

    assert synthesise(returns_wrong, TREE, LINE).bt == wrong  # rewriting keeps it as it is
    with pytest.raises(NotEquivalentError):
        synthesise(returns_wrong, TREE, LINE, rng_seed=1)


# ------------------------------------------------------------------------ verification
def test_each_state_passes_exactly_one_leaf_path_whose_action_the_tree_decides():
    """Law: the leaf paths in observed space partition the states, boundaries included, and
    each leaf's path carries its action; derived columns are their forms at exact
    thresholds."""
    paths = path_tests(TREE)
    assert len(paths) == TREE.get_n_leaves()
    derived = {exact_threshold(t) for f, t in zip(TREE.tree_.feature, TREE.tree_.threshold,
                                                  strict=True) if f >= 3}
    forms = [(what, t) for tests, _ in paths for what, t, _ in tests
             if not isinstance(what, int)]
    assert forms and {t for _, t in forms} <= derived
    assert {what for what, _ in forms} <= set(FORMS)
    states = np.concatenate([verification_states(TREE, LINE, n_random=300).states, STATES])
    predicted = TREE.predict(states)
    for state, action in zip(states, predicted, strict=True):
        passed = [a for tests, a in paths if satisfies(state, tests)]
        assert passed == [action]


def test_the_verifier_states_are_a_state_per_region_its_crossings_and_the_random_draw():
    check = verification_states(TREE, LINE, n_random=500, seed=4)
    assert check.regions == TREE.get_n_leaves()
    assert check.regions_found == check.regions  # every leaf holds training samples
    assert check.boundary_states > 0 and check.random_states == 500
    assert check.states.dtype == np.float32
    assert len(check.states) == check.regions_found + check.boundary_states + 500
    random = LINE.sample_features(500, np.random.default_rng(4)).astype(np.float32)
    assert np.array_equal(check.states[-500:], random)
    head = check.states[:-500]
    assert len(set(TREE.apply(head).tolist())) == check.regions  # every leaf is reached
    # what was tried is a record, not a scratchpad (mutant: the dataclass not frozen)
    with pytest.raises(dataclasses.FrozenInstanceError):
        check.regions = 0  # type: ignore[misc]


def test_the_verifier_draws_twenty_thousand_random_states_with_seed_zero_by_default():
    default = verification_states(TREE, LINE)
    assert default.random_states == 20_000
    assert np.array_equal(default.states,
                          verification_states(TREE, LINE, n_random=20_000, seed=0).states)
    assert verify_relational(correct_bt(TREE), TREE, LINE) == len(default.states)


def test_verify_relational_checks_its_seeds_draw_zero_by_default():
    odd = LINE.sample_features(200, np.random.default_rng(1)).astype(np.float32)[5]
    wrong = wrong_at(correct_bt(TREE), odd, TREE)
    assert verify_relational(wrong, TREE, LINE, n_random=200) > 200
    with pytest.raises(NotEquivalentError, match="relational tree"):
        verify_relational(wrong, TREE, LINE, n_random=200, seed=1)
