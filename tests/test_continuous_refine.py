"""Refinement by return of command trees (issue 25, Imitation-BT+ for continuous actions) and
the cached continuous steps of :mod:`ibt.runs.continuous`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.tree import DecisionTreeRegressor

from ibt.distill.continuous import regression_signature, regressor_doc, regressor_from_doc
from ibt.engine.synthesis import command_tree_of
from ibt.profiles import config
from ibt.refine.commands import CommandArrays, CommandPopulation, refine_commands
from ibt.runs import continuous
from ibt.synth.commands import command_tree
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import RefineConfig

CAR = get_task("MountainCarContinuous-v0")
TINY = RefineConfig(stages=("cma",), episodes=300, cma_generations=3, cma_episodes=3,
                    cma_popsize=4, sweep_episodes=4, selection_episodes=6, n_envs=8)


@pytest.fixture(scope="module")
def car_arrays() -> CommandArrays:
    """A 4-leaf command tree of MountainCarContinuous: push left when slow and left, else right
    (made by hand: no expert needed)."""
    rng = np.random.default_rng(0)
    x = CAR.sample_features(2000, rng)
    y = np.where(x[:, 1] < 0, -0.8, 0.9)[:, None] + 0.05 * (x[:, 0:1] > -0.5)
    tree = DecisionTreeRegressor(max_leaf_nodes=4, random_state=0).fit(x, y)
    return CommandArrays.from_command_tree(command_tree(tree, CAR, 4))


def test_regressor_document_round_trips_exactly():
    x = np.random.default_rng(1).normal(size=(400, 3)).astype(np.float32)
    y = np.c_[x[:, 0], np.sin(x[:, 2])]
    tree = DecisionTreeRegressor(max_leaf_nodes=9, random_state=0).fit(x, y)
    again = regressor_from_doc(json.loads(json.dumps(regressor_doc(tree))))
    assert regression_signature(again) == regression_signature(tree)
    assert np.array_equal(again.predict(x), tree.predict(x))


def test_command_arrays_document_and_tree_decide_alike(car_arrays):
    again = CommandArrays.from_doc(json.loads(json.dumps(car_arrays.to_doc())))
    x = CAR.sample_features(3000, np.random.default_rng(2))
    assert np.array_equal(again.actions(x), car_arrays.actions(x))
    tree = command_tree_of(car_arrays, CAR)
    assert np.array_equal(tree.actions(x), car_arrays.actions(x))
    population = CommandPopulation(car_arrays, car_arrays.structure.threshold[None],
                                   car_arrays.values[None])
    assert np.array_equal(population.decide(x, np.zeros(len(x), dtype=np.int64)),
                          car_arrays.actions(x))


def test_refinement_is_deterministic_keeps_shape_and_rounds_inside_the_box(car_arrays):
    first = refine_commands(car_arrays, CAR, TINY, seed=3, progress=False)
    second = refine_commands(car_arrays, CAR, TINY, seed=3, progress=False)
    assert json.dumps(first.to_doc()["candidates"]) == json.dumps(
        second.to_doc()["candidates"])
    assert first.selection_means == second.selection_means
    assert first.episodes <= TINY.episodes
    best = first.best
    assert best.n_leaves <= car_arrays.n_leaves and best.n_commands == car_arrays.n_commands
    assert np.array_equal(best.values, np.round(best.values, 2))
    assert (best.values >= -1).all() and (best.values <= 1).all()
    # the chosen candidate is the best on the held-out selection episodes
    assert first.selection_means[first.best_index] == max(first.selection_means)
    restored = type(first).from_doc(json.loads(json.dumps(first.to_doc())))
    assert restored.best_index == first.best_index
    assert np.array_equal(restored.best.values, best.values)


def test_refinement_refuses_discrete_tasks_and_other_stages(car_arrays):
    from dataclasses import replace

    with pytest.raises(ValueError, match="discrete"):
        refine_commands(car_arrays, get_task("CartPole-v1"), TINY, progress=False)
    with pytest.raises(ValueError, match="CMA-ES stages only"):
        refine_commands(car_arrays, CAR, replace(TINY, stages=("cma", "prune")),
                        progress=False)


@pytest.mark.slow
def test_the_cached_steps_run_under_smoke_and_hit_the_second_time(tmp_path):
    cfg = config("smoke", cache_dir=tmp_path / "cache", data_dir=tmp_path / "data")
    point = continuous.BoxPoint(CAR.name, "sac", "dagger", 0, 4, refined=True)
    first = continuous.point_row(cfg, point)
    kinds = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert {"box-distill", "box-commands", "box-refine", "box-eval"} <= set(kinds)
    again = continuous.point_row(cfg, point)
    assert first == again
    assert first["leaves"] <= 4 and first["bt_nodes"] >= 1
    bt = continuous.point_bt(cfg, point)
    assert bt.commands is not None and bt.node_count == first["bt_nodes"]
