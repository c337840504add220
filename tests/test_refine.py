"""Tree arrays and refinement by return: exact rebuilding, exact simplification, budgets, seeds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.evaluate.policies import CompiledTree
from ibt.evaluate.rollouts import FINAL_SEED_BASE, REFINE_SEED_BASE, SELECTION_SEED_BASE
from ibt.refine.by_return import Population, RefineConfig, refine
from ibt.refine.tree_arrays import TreeArrays
from ibt.synth.rules import leaf_witnesses
from ibt.tasks.catalogue import get_task


def _random_tree(seed: int, leaves: int, n_actions: int, skip_class: bool = False
                 ) -> tuple[DecisionTreeClassifier, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(600, 3)).astype(np.float32)
    y = rng.integers(0, n_actions, size=len(x))
    if skip_class:  # classes_ a strict subset of the actions, e.g. {0, 2}
        y = np.where(y == 1, 0, y)
    tree = DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, y)
    states = np.concatenate([rng.normal(size=(2_000, 3)).astype(np.float32),
                             leaf_witnesses(tree, np.full(3, -np.inf), np.full(3, np.inf))])
    return tree, states


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), leaves=st.integers(2, 40), n_actions=st.integers(2, 5),
       skip=st.booleans())
def test_rebuilt_tree_decides_as_the_source(seed, leaves, n_actions, skip):
    # Expect: arrays -> sklearn -> every executor decides as the fitted tree, boundaries included
    tree, states = _random_tree(seed, leaves, n_actions, skip_class=skip and n_actions > 2)
    arrays = TreeArrays.from_sklearn(tree)
    rebuilt = arrays.to_sklearn()
    expected = tree.predict(states)
    assert np.array_equal(arrays.predict(states), expected)
    assert np.array_equal(rebuilt.predict(states), expected)
    assert np.array_equal(CompiledTree(rebuilt).predict(states), expected)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), leaves=st.integers(2, 40), cut=st.integers(0, 10**6),
       side=st.sampled_from([np.inf, -np.inf, 0.0]))
def test_simplification_is_exact_and_never_larger(seed, leaves, cut, side):
    # Expect: fixing a split to one side, then simplifying, decides as before and shrinks
    tree, states = _random_tree(seed, leaves, 3)
    arrays = TreeArrays.from_sklearn(tree)
    splits = np.flatnonzero(~arrays.is_leaf)
    threshold = arrays.threshold.copy()
    threshold[splits[cut % len(splits)]] = side
    changed = arrays.with_parameters(threshold=threshold)
    simple = changed.simplified()
    assert np.array_equal(simple.predict(states), changed.predict(states))
    assert simple.n_leaves <= changed.n_leaves
    assert simple.node_count == 2 * simple.n_leaves - 1


def test_population_decides_each_member_with_its_own_parameters():
    tree, states = _random_tree(3, 12, 3)
    arrays = TreeArrays.from_sklearn(tree)
    other = arrays.threshold + 0.3 * ~arrays.is_leaf
    flipped = (arrays.action + 1) % 3
    population = Population(arrays, np.vstack([arrays.threshold, other]),
                            np.vstack([arrays.action, flipped]))
    members = np.arange(len(states)) % 2
    got = population.decide(states, members)
    assert np.array_equal(got[members == 0], arrays.predict(states[members == 0]))
    second = arrays.with_parameters(other, flipped)
    assert np.array_equal(got[members == 1], second.predict(states[members == 1]))


def _cartpole_tree() -> DecisionTreeClassifier:
    # a hand-made 3-leaf CartPole tree: push towards where the pole is falling
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.2, 0.2, size=(400, 4)).astype(np.float32)
    y = (x[:, 3] + 0.5 * x[:, 2] > 0).astype(np.int64)
    return DecisionTreeClassifier(max_leaf_nodes=3, random_state=0).fit(x, y)


TINY = RefineConfig(stages=("cma", "leaves", "prune"), episodes=400, cma_generations=3,
                    cma_episodes=4, cma_popsize=6, sweep_episodes=4, sweep_rounds=2,
                    selection_episodes=5, n_envs=16)


def test_refine_is_deterministic_and_within_budget():
    task = get_task("CartPole-v1")
    first = refine(_cartpole_tree(), task, TINY, seed=1, progress=False)
    second = refine(_cartpole_tree(), task, TINY, seed=1, progress=False)
    assert first.episodes <= TINY.episodes
    assert first.episodes == second.episodes and first.steps == second.steps
    assert first.best_index == second.best_index
    for a, b in zip(first.candidates, second.candidates, strict=True):
        assert np.array_equal(a.threshold, b.threshold)
        assert np.array_equal(a.action, b.action)
    assert [s["stage"] for s in first.stages] == ["cma", "leaves", "prune"]


def test_refine_respects_a_leaf_limit():
    task = get_task("CartPole-v1")
    config = RefineConfig(**{**TINY.as_params(), "stages": ("prune",), "max_leaves": 2})
    record = refine(_cartpole_tree(), task, config, seed=0, progress=False)
    assert record.best.n_leaves <= 2
    assert record.best_tree.get_n_leaves() == record.best.n_leaves


def test_refinement_seeds_are_disjoint_from_selection_and_final_ones():
    # Expect: final and selection blocks end below the refinement block, for any run seed
    assert FINAL_SEED_BASE + 1_000_000 <= SELECTION_SEED_BASE
    assert SELECTION_SEED_BASE + 10_000 * 100 <= REFINE_SEED_BASE


@pytest.mark.parametrize("bad", [{"episodes": 0}, {"stages": ("anneal",)}, {"cma_sigma": 0.0},
                                 {"max_leaves": 0}, {"n_envs": 0}])
def test_bad_refine_configs_are_refused(bad):
    with pytest.raises(ValueError):
        RefineConfig(**bad)


def test_cli_refines_a_tree_file_to_a_leaf_limit(tmp_path, capsys):
    from ibt.cli import main
    from ibt.distill.tree_file import load_tree_file, save_tree_file
    from ibt.tasks.catalogue import get_task

    source = save_tree_file(tmp_path / "tree.json", _cartpole_tree(), get_task("CartPole-v1"),
                            {"algo": "dqn"})
    out = tmp_path / "small.json"
    assert main(["refine", str(source), "-o", str(out), "--max-leaves", "2",
                 "--episodes", "300", "--quiet"]) == 0
    doc = load_tree_file(out)
    assert doc["tree"].get_n_leaves() <= 2 and doc["refined_from"] == str(source)
    assert "2 leaves" in capsys.readouterr().out or doc["tree"].get_n_leaves() == 1
    # a bad budget is refused before any work, and nothing is written
    again = tmp_path / "again.json"
    assert main(["refine", str(source), "-o", str(again), "--episodes", "0"]) == 2
    assert not again.exists()
