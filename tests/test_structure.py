"""Structure search by return: the batched forest decides as each tree, mutations stay within
the leaf limit, and a run is deterministic in its seed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

import ibt
from ibt.refine.forest import Forest
from ibt.refine.structure import evolve, reselect
from ibt.refine.structure_mutations import TreeMutator, arrays, nested
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.settings import EvolveConfig


def _tree(seed: int, leaves: int, n_features: int = 4, n_actions: int = 3) -> TreeArrays:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(300, n_features)).astype(np.float32)
    y = rng.integers(n_actions, size=300)
    fit = DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, y)
    return TreeArrays.from_sklearn(fit)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(2, 12)), min_size=1, max_size=5),
       st.integers(0, 10**6))
def test_forest_decides_as_each_tree(specs, seed):
    trees = [_tree(s, leaves) for s, leaves in specs]
    x = np.random.default_rng(seed).normal(size=(200, 4)).astype(np.float32)
    members = np.arange(200) % len(trees)
    expected = np.array([trees[m].predict(x[i:i + 1])[0] for i, m in enumerate(members)])
    # Expect: row i routed through tree members[i] exactly as that tree alone decides
    assert np.array_equal(Forest(trees).decide(x, members), expected)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 10), st.integers(0, 10**6))
def test_nested_round_trip_and_mutations_keep_the_limit(tree_seed, leaves, mutation_seed):
    task = ibt.get_task("CartPole-v1")
    tree = _tree(tree_seed, leaves, n_features=4, n_actions=2)
    x = np.random.default_rng(0).normal(size=(300, 4)).astype(np.float32)
    assert np.array_equal(arrays(nested(tree), 4, 2).predict(x), tree.predict(x))
    mutator = TreeMutator(task, EvolveConfig(max_leaves=leaves, use_expert=False),
                          np.random.default_rng(mutation_seed), None)
    mutator.refresh(x)
    root = nested(tree)
    for _ in range(20):
        root = nested(arrays(mutator.mutate(root), 4, 2))
        assert arrays(root, 4, 2).n_leaves <= leaves  # the search never outgrows its limit


def _small_search(selection_episodes: int, finalists: int) -> EvolveConfig:
    """A CartPole search of a few seconds, on reward alone."""
    return EvolveConfig(max_leaves=3, episodes=120, mu=2, lam=4, generation_episodes=4,
                        pool_episodes=2, selection_episodes=selection_episodes,
                        finalists=finalists, n_envs=8, use_expert=False)


def test_a_small_search_is_deterministic_and_within_its_limit():
    task = ibt.get_task("CartPole-v1")
    source = _tree(0, 6, n_features=4, n_actions=2)
    config = _small_search(selection_episodes=4, finalists=3)
    first = evolve([source], task, config, seed=3, progress=False)
    second = evolve([source], task, config, seed=3, progress=False)
    assert first.best.n_leaves <= 3 and first.episodes <= 120
    assert first.selection_means == second.selection_means
    assert np.array_equal(first.best.threshold, second.best.threshold)
    assert first.random_steps_per_second > 0 and first.steps > 0


def test_choosing_again_on_more_episodes_is_the_search_run_with_them():
    """The search's path does not depend on its held-out choice, so :func:`reselect` of a
    cached search equals the search run with that many selection episodes."""
    task = ibt.get_task("CartPole-v1")
    source = _tree(1, 6, n_features=4, n_actions=2)
    config = _small_search(selection_episodes=3, finalists=4)
    short = evolve([source], task, config, seed=5, progress=False)
    direct = evolve([source], task, replace(config, selection_episodes=9), seed=5,
                    progress=False)
    again = reselect(short, task, 9)
    assert again.selection_means == direct.selection_means
    assert again.best_index == direct.best_index and again.config == direct.config
    assert all(np.array_equal(a.threshold, b.threshold)
               for a, b in zip(again.finalists, direct.finalists, strict=True))
    assert again.episodes == short.episodes and again.cpu_seconds >= short.cpu_seconds
    assert short.selection_means != again.selection_means  # the record chosen from is kept


class _ScoredExpert:
    """An expert whose scores disagree with its majority: most states prefer action 0 by a
    hair, a few prefer action 1 by far."""

    def scores(self, obs: np.ndarray) -> np.ndarray:
        strong = np.asarray(obs)[:, 0] > 1.0
        return np.where(strong[:, None], [[0.0, 5.0]], [[1.0, 0.9]])

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.argmax(self.scores(obs), axis=1)


def test_the_score_leaf_rule_picks_the_best_mean_score_where_the_vote_picks_the_majority():
    task = ibt.get_task("CartPole-v1")
    x = np.random.default_rng(1).normal(size=(400, 4)).astype(np.float32)
    assert 0.05 < (x[:, 0] > 1.0).mean() < 0.3  # a minority prefers action 1, strongly
    picked = {}
    for rule in ("vote", "score"):
        mutator = TreeMutator(task, EvolveConfig(max_leaves=4, leaf_rule=rule),
                              np.random.default_rng(0), _ScoredExpert())
        mutator.refresh(x)
        picked[rule] = mutator._leaf_action(np.ones(len(mutator.pool), dtype=bool))
    # Expect: the majority label (0) by vote; the action of the highest mean score (1) by score
    assert picked == {"vote": 0, "score": 1}


def test_the_leaf_rule_is_checked_and_kept_out_of_old_cache_keys():
    assert "leaf_rule" not in EvolveConfig().as_params()  # the keys of earlier runs stay
    assert EvolveConfig(leaf_rule="score").as_params()["leaf_rule"] == "score"
    with pytest.raises(ValueError, match="leaf_rule 'q' is not one of vote, score"):
        EvolveConfig(leaf_rule="q")
