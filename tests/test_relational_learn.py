"""Learning relational tests (issue 26, part B): the learner, its tree as plain data, the loop's
``imitation-bt+rel`` method and refinement by return of relational trees."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ibt.bt.linear import FeatureMap, LinearForm
from ibt.distill.loop import METHODS, tree_signature
from ibt.distill.relational import (
    RelationalSettings,
    RelationalTreeClassifier,
    candidate_map,
    fit_relational_tree,
    relational_tests,
)


def _go_to_target(n: int = 4000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The go-to-target rule's labels: right (2) below the diagonal band, left (0) above."""
    x = np.random.default_rng(seed).uniform(-1, 1, (n, 2)).astype(np.float32)
    d = x[:, 0].astype(np.float64) - x[:, 1]
    return x, np.where(d < -0.05, 2, np.where(d > 0.05, 0, 1))


def test_the_learner_finds_the_difference_in_three_leaves():
    x, y = _go_to_target()
    tree = fit_relational_tree(x, y, max_leaf_nodes=8)
    assert isinstance(tree, RelationalTreeClassifier)
    assert tree.get_n_leaves() == 3 and relational_tests(tree) == 2
    assert tree.feature_map_ == FeatureMap(2, (LinearForm(0, 1, 1.0, -1.0),))
    assert (tree.predict(x) == y).all()
    # its tree_ is an ordinary scikit-learn tree on augmented rows
    from sklearn.tree import DecisionTreeClassifier

    from ibt.evaluate.policies import CompiledTree
    from ibt.refine.tree_arrays import TreeArrays

    grid = np.random.default_rng(1).uniform(-1, 1, (3000, 2)).astype(np.float32)
    augmented = tree.feature_map_.augment(grid)
    plain = DecisionTreeClassifier.predict(tree, augmented)
    assert (tree.predict(grid) == plain).all()
    assert (CompiledTree(tree).predict(grid) == plain).all()
    assert (TreeArrays.from_sklearn(tree).predict(augmented) == plain).all()


def test_axis_aligned_labels_get_axis_aligned_splits():
    x = np.random.default_rng(2).uniform(-1, 1, (4000, 3)).astype(np.float32)
    y = (x[:, 0] <= 0.3).astype(int) + 2 * (x[:, 2] <= -0.2)
    tree = fit_relational_tree(x, y, max_leaf_nodes=6)
    assert relational_tests(tree) == 0 and tree.feature_map_.forms == ()
    assert (tree.predict(x) == y).all()


def test_a_relational_split_must_beat_the_axis_split_by_the_margin():
    x, y = _go_to_target()
    never = fit_relational_tree(x, y, max_leaf_nodes=8,
                                settings=RelationalSettings(margin=1e9))
    assert relational_tests(never) == 0
    assert relational_tests(fit_relational_tree(x, y, max_leaf_nodes=8)) > 0


def test_binary_features_get_no_derived_columns():
    x = np.random.default_rng(3).normal(size=(500, 4)).astype(np.float32)
    x[:, 3] = x[:, 3] > 0
    forms = candidate_map(x).forms
    assert forms and all(3 not in (f.i, f.j) for f in forms)


def test_the_learner_is_deterministic_and_respects_its_limits():
    x, y = _go_to_target(3000, seed=4)
    y = np.where(np.random.default_rng(5).random(len(y)) < 0.1, 1, y)  # noisy labels
    a = fit_relational_tree(x, y, max_leaf_nodes=6, seed=7)
    b = fit_relational_tree(x, y, max_leaf_nodes=6, seed=7)
    assert tree_signature(a) == tree_signature(b)
    assert a.get_n_leaves() <= 6
    assert fit_relational_tree(x, y, max_depth=2).get_depth() <= 2


def test_a_relational_tree_round_trips_as_plain_data():
    from ibt.cache.payloads import difference, dumps_npz, loads_npz
    from ibt.distill.tree_codec import PlainDataError, tree_from_data, tree_to_data

    x, y = _go_to_target()
    tree = fit_relational_tree(x, y, max_leaf_nodes=4)
    doc = json.loads(json.dumps(tree_to_data(tree)))
    back = tree_from_data(doc)
    assert type(back) is RelationalTreeClassifier and difference(tree, back) is None
    assert tree_signature(back) == tree_signature(tree)
    assert (back.predict(x) == tree.predict(x)).all()
    value = {"trees": [tree]}
    assert difference(value, loads_npz("ibt-distillation", dumps_npz("ibt-distillation",
                                                                     value))) is None
    # a feature map that does not match the tree's columns is refused
    body = doc["value"]["__sklearn_relational_tree__"]
    body["feature_map_"]["forms"].append({"features": [1, 0], "weights": [1.0, 1.0]})
    with pytest.raises(PlainDataError):
        tree_from_data(doc)


def test_the_signature_tells_feature_maps_apart():
    from ibt.distill.relational import as_relational

    x, y = _go_to_target()
    tree = fit_relational_tree(x, y, max_leaf_nodes=4)
    other = as_relational(tree, FeatureMap(2, (LinearForm(0, 1, 1.0, -2.0),)))
    assert tree_signature(other) != tree_signature(tree)


def test_the_paper_methods_are_unchanged_and_the_relational_one_is_named():
    from ibt.distill.loop import fit_cart, fit_relational

    assert [m for m, spec in METHODS.items() if spec.fit is fit_cart] == [
        "bc", "dagger", "viper", "imitation-bt"]
    assert METHODS["imitation-bt+rel"].fit is fit_relational
    assert METHODS["imitation-bt+rel"].schedule == METHODS["imitation-bt"].schedule


@pytest.fixture(scope="module")
def go_to_target():
    """The example task of a user's module and its committed PPO agent."""
    from ibt.experts.expert import load_expert
    from tests.fixtures import go_to_target as module

    return module.GO_TO_TARGET, load_expert(module.GO_TO_TARGET, "ppo", module.CHECKPOINT)


@pytest.mark.slow
def test_the_loop_distils_relational_trees_and_refinement_keeps_them(go_to_target):
    from ibt.distill.loop import DistillConfig, distill
    from ibt.evaluate.policies import TreePolicy
    from ibt.evaluate.rollouts import rollout
    from ibt.refine.by_return import task_config
    from ibt.refine.relational import augmented_task, best_tree, refine_relational

    task, expert = go_to_target
    config = DistillConfig.for_task(task, method="imitation-bt+rel", n_iterations=3,
                                    labels_per_iteration=300, selection_episodes=4,
                                    max_leaf_nodes=6)
    run = distill(task, expert, config, seed=0, progress=False)
    tree = run.best_tree
    assert isinstance(tree, RelationalTreeClassifier) and relational_tests(tree) >= 1
    again = distill(task, expert, config, seed=0, progress=False)
    assert [tree_signature(t) for t in again.trees] == [tree_signature(t) for t in run.trees]
    # the augmented task's features are the tree's columns
    aug = augmented_task(task, tree.feature_map_)
    obs = np.random.default_rng(0).uniform(-1, 1, (5, 2)).astype(np.float32)
    assert np.array_equal(aug.features(obs), tree.feature_map_.augment(obs))
    assert aug.n_features == tree.feature_map_.width
    record = refine_relational(tree, task, task_config(task, episodes=300, cma_generations=2,
                                                       cma_episodes=2, sweep_episodes=2,
                                                       sweep_rounds=1, selection_episodes=4,
                                                       n_envs=8, max_leaves=3),
                               seed=0, progress=False)
    refined = best_tree(record)
    assert isinstance(refined, RelationalTreeClassifier) and refined.get_n_leaves() <= 3
    states = np.random.default_rng(1).uniform(-1, 1, (2000, 2)).astype(np.float32)
    assert (record.best.predict(refined.feature_map_.augment(states))
            == refined.predict(states)).all()
    seeds = list(range(10))
    got = rollout(task, TreePolicy(task, refined).act, seeds).returns
    assert np.array_equal(got, rollout(aug, lambda o: record.best.predict(aug.features(o)),
                                       seeds).returns)


@pytest.mark.slow
def test_the_cli_distils_a_relational_tree_file_and_synthesises_it(tmp_path, capsys):
    from ibt.cli import main
    from ibt.distill.tree_file import load_tree_file
    from tests.fixtures.go_to_target import CHECKPOINT

    tree_path, bt_path = tmp_path / "tree.json", tmp_path / "bt.json"
    common = ["--env-module", "tests.fixtures.go_to_target"]
    assert main(["distill", "GoToTarget-v0", "ppo", "--checkpoint", str(CHECKPOINT),
                 "--method", "imitation-bt+rel", "--iterations", "2", "--labels", "300",
                 "--selection-episodes", "2", "-o", str(tree_path), "--quiet", *common]) == 0
    tree = load_tree_file(tree_path)["tree"]
    assert isinstance(tree, RelationalTreeClassifier) and relational_tests(tree) >= 1
    assert main(["synthesize", str(tree_path), "-o", str(bt_path), *common]) == 0
    from ibt.bt.json_io import load_json

    assert load_json(bt_path).relational_count >= 1


@pytest.mark.slow
def test_a_relational_front_row_under_the_smoke_profile(tmp_path):
    from dataclasses import replace

    import ibt
    from ibt.runs.relational import REFINED, relational_table

    cfg = replace(ibt.config("smoke"), cache_dir=tmp_path / "cache", progress=False)
    table = relational_table(cfg, [("CartPole-v1", "dqn")], seeds=[0], leaves=[2])
    row = table.iloc[0]
    assert row["method"] == REFINED and row["leaves"] <= 2
    assert 0 <= row["relational_tests"] <= row["bt_conditions"]
    assert {"task", "expert", "seed", "bt_nodes", "retention_norm"} <= set(table.columns)
    again = relational_table(cfg, [("CartPole-v1", "dqn")], seeds=[0], leaves=[2])  # cached
    assert again.equals(table)
