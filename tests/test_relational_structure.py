"""Structure search with relational tests (Imitation-BT+SR): widened and compacted trees decide
as the originals, the search is deterministic and within its limit, its winner is a relational
tree over only the columns it tests, and the expert labels the observed part of a pool row."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

import ibt
from ibt.bt.linear import FeatureMap, LinearForm
from ibt.distill.relational import (
    RelationalTreeClassifier,
    candidate_map,
    one_significant,
    scaled_candidate_map,
)
from ibt.engine.budgets import relational_search_config as search_config
from ibt.refine.relational import augmented_task
from ibt.refine.relational_structure import (
    compact,
    evolve_relational,
    search_map,
    seed_columns,
    widen,
    winner,
)
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.settings import EvolveConfig


def _wide_tree(seed: int, leaves: int, fmap: FeatureMap) -> TreeArrays:
    rng = np.random.default_rng(seed)
    x = fmap.augment(rng.normal(size=(400, fmap.n_features)).astype(np.float32))
    y = rng.integers(3, size=400)
    return TreeArrays.from_sklearn(
        DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, y))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 12), st.integers(0, 10**6))
def test_compact_keeps_every_decision_and_only_the_tested_columns(tree_seed, leaves, seed):
    fmap = FeatureMap.pairs(4)
    tree = _wide_tree(tree_seed, leaves, fmap)
    small_tree, small = compact(tree, fmap)
    x = np.random.default_rng(seed).normal(size=(300, 4)).astype(np.float32)
    assert np.array_equal(small_tree.predict(small.augment(x)), tree.predict(fmap.augment(x)))
    tested = {int(f) for f, leaf in zip(tree.feature, tree.is_leaf, strict=True)
              if not leaf and f >= 4}
    assert len(small.forms) == len(tested)  # the map keeps the derived columns tested, no more
    assert set(small.forms) == {fmap.form(c) for c in tested}


def test_widen_reads_the_observed_columns_of_an_augmented_row():
    fmap = FeatureMap.pairs(4)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, 4)).astype(np.float32)
    tree = TreeArrays.from_sklearn(
        DecisionTreeClassifier(max_leaf_nodes=6, random_state=0).fit(x, rng.integers(2, size=300)))
    wide = widen(tree, fmap.width)
    assert wide.n_features == fmap.width
    assert np.array_equal(wide.predict(fmap.augment(x)), tree.predict(x))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 12), st.integers(0, 10**6), st.integers(0, 6))
def test_seed_columns_keep_every_seed_trees_decisions(tree_seed, leaves, seed, shared):
    """A relational seed tree (its own derived columns, some among the candidates, some not)
    and an axis-aligned one decide over the search's columns exactly as they did."""
    own = FeatureMap(4, (LinearForm(0, 1, 1.0, 2.0), LinearForm(2, 3, 0.5, -1.0),
                         *FeatureMap.pairs(4).forms[:shared]))
    rng = np.random.default_rng(tree_seed)
    x_fit = rng.normal(size=(400, 4)).astype(np.float32)
    y = rng.integers(3, size=400)
    relational = RelationalTreeClassifier(max_leaf_nodes=leaves, random_state=0).fit_relational(
        x_fit, y, own)
    axis = DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=0).fit(x_fit, y)
    candidates = FeatureMap.pairs(4)
    columns, (wide_axis, wide_relational) = seed_columns([axis, relational], candidates)
    assert columns.forms[:len(candidates.forms)] == candidates.forms  # candidates come first
    assert set(own.forms) <= set(columns.forms) and len(set(columns.forms)) == columns.width - 4
    x = np.random.default_rng(seed).normal(size=(300, 4)).astype(np.float32)
    assert np.array_equal(wide_relational.predict(columns.augment(x)), relational.predict(x))
    assert np.array_equal(wide_axis.predict(columns.augment(x)), axis.predict(x))
    assert seed_columns([axis], candidates)[0] == candidates  # no relational seed: unchanged


def test_the_augmented_task_gives_the_expert_observations():
    task = ibt.get_task("CartPole-v1")
    fmap = FeatureMap.pairs(4)
    wide = augmented_task(task, fmap)
    obs = np.random.default_rng(1).normal(size=(5, 4)).astype(np.float32)
    assert np.array_equal(wide.observations(wide.features(obs)), obs)


def test_a_small_relational_search_is_deterministic_and_its_winner_relational():
    task = ibt.get_task("CartPole-v1")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, 4)).astype(np.float32)
    source = TreeArrays.from_sklearn(
        DecisionTreeClassifier(max_leaf_nodes=6, random_state=0).fit(x, rng.integers(2, size=300)))
    config = EvolveConfig(max_leaves=3, episodes=120, mu=2, lam=4, generation_episodes=4,
                          pool_episodes=2, selection_episodes=4, finalists=3, n_envs=8,
                          use_expert=False)
    first = evolve_relational([source], task, config, seed=3, progress=False)
    second = evolve_relational([source], task, config, seed=3, progress=False)
    assert first.best.n_leaves <= 3 and first.episodes <= 120
    assert first.selection_means == second.selection_means
    assert np.array_equal(first.best.threshold, second.best.threshold)
    fmap = search_map(task, source)
    assert first.best.n_features == fmap.width  # the search read every candidate column
    tree = winner(first)
    assert isinstance(tree, RelationalTreeClassifier)
    states = task.sample_features(500, np.random.default_rng(2))
    assert np.array_equal(tree.predict(states), first.best.predict(fmap.augment(states)))


@settings(max_examples=50, deadline=None)
@given(st.floats(1e-6, 1e6) | st.floats(-1e6, -1e-6))
def test_one_significant_digit_stays_near_and_readable(value):
    rounded = one_significant(value)
    assert np.sign(rounded) == np.sign(value)
    assert abs(rounded - value) <= 0.5 * 10 ** np.floor(np.log10(abs(value))) * (1 + 1e-9)
    assert len(f"{abs(rounded):.0e}".split("e")[0]) == 1  # one digit before the exponent


def test_scaled_candidates_relate_features_of_different_scales():
    rng = np.random.default_rng(0)
    x = np.c_[rng.normal(0, 0.3, 2000), rng.normal(0, 0.02, 2000), rng.integers(2, size=2000),
              rng.normal(0, 0.3, 2000)]
    fmap = scaled_candidate_map(x)
    assert {f.i for f in fmap.forms} | {f.j for f in fmap.forms} == {0, 1, 3}  # no binary flag
    weights_01 = {(f.w1, f.w2) for f in fmap.forms if (f.i, f.j) == (0, 1)}
    assert (1.0, 20.0) in weights_01 and (1.0, -20.0) in weights_01  # spreads 0.3 / 0.02 = 15
    fixed = candidate_map(x)
    def weights_of(m: FeatureMap, pair: tuple[int, int]) -> set[tuple[float, float]]:
        return {(f.w1, f.w2) for f in m.forms if (f.i, f.j) == pair}
    assert weights_of(fmap, (0, 3)) == weights_of(fixed, (0, 3))  # one scale: fixed weights


def test_a_search_budget_below_one_generation_is_refused():
    cfg = ibt.config("paper")
    task = ibt.get_task("LunarLander-v3")
    assert search_config(cfg, task, 9, 40_000).episodes == 40_000
    assert search_config(cfg, task, 9).episodes == task.evolve.episodes
    with pytest.raises(ValueError, match="below one generation"):
        search_config(cfg, task, 9, 1)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 12), st.integers(1, 60))
def test_forest_reads_only_the_tested_columns_and_decides_as_on_every_column(seed, leaves,
                                                                            rows):
    """The search's rollouts compute only the derived columns some split tests
    (:meth:`Forest.reader`); decisions equal the Forest's on the fully augmented rows,
    for a rollout's few rows (walked in Python) and for full batches alike."""
    from ibt.refine.forest import Forest
    from ibt.tasks.catalogue import get_task

    task = get_task("CartPole-v1")
    fmap = FeatureMap.pairs(task.n_features)
    wide = augmented_task(task, fmap)
    trees = [_wide_tree(seed + k, leaves, fmap) for k in range(3)]
    rng = np.random.default_rng(seed)
    obs = (rng.normal(size=(rows, task.n_features)) * 3).astype(np.float32)
    members = rng.integers(len(trees), size=rows)
    forest = Forest(trees)
    expected = forest.decide(wide.features(obs), members)
    assert np.array_equal(forest.decide_columns(forest.reader(wide)(obs), members), expected)
    for k, tree in enumerate(trees):
        chosen = members == k
        if not chosen.any():
            continue
        assert np.array_equal(expected[chosen], tree.predict(wide.features(obs[chosen])))
