"""Each stage's settings (ibt.engine.budgets) from a task's catalogue entry and a profile: the
imitation loop's label floor and iteration cap, the continuous distillation's selection and
leaf limit, a refinement shrunk under ``smoke`` or scaled with its CMA-ES generations, the
structure search's budget floors and its polishes. Quick: settings only, nothing runs."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

import ibt
from ibt.engine import budgets
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import EvolveConfig, RefineConfig, TaskBudget

PAPER = ibt.config("paper")
SMOKE = ibt.config("smoke")
CARTPOLE = get_task("CartPole-v1")
PENDULUM = get_task("Pendulum-v1")


def _with(task, **budget):
    return replace(task, budget=TaskBudget(**budget))


# -- distil -------------------------------------------------------------------------------

@pytest.mark.parametrize("labels, scale, expected", [
    (1000, 1.0, 1000), (1000, 0.3, 300), (100, 0.3, 50), (166, 0.3, 50), (170, 0.3, 51),
    (50, 1.0, 50), (51, 1.0, 51), (10, 1.0, 50)])
def test_labels_are_scaled_by_the_profile_but_never_below_fifty(labels, scale, expected):
    cfg = replace(PAPER, labels_scale=scale)
    got = budgets.distill_config(cfg, _with(CARTPOLE, labels_per_iteration=labels))
    assert got.labels_per_iteration == expected


@pytest.mark.parametrize("cap, iterations, expected", [
    (None, 50, 50), (10, 50, 10), (60, 50, 50), (50, 50, 50), (None, 4, 4), (3, 4, 3)])
def test_iterations_are_the_profiles_capped_by_the_task(cap, iterations, expected):
    cfg = replace(PAPER, n_iterations=iterations)
    assert budgets.distill_config(cfg, _with(CARTPOLE, max_iterations=cap)).n_iterations == (
        expected)


def test_selection_episodes_are_the_profiles_times_the_tasks_scale_and_overrides_win():
    cfg = replace(PAPER, selection_episodes=20)
    got = budgets.distill_config(cfg, _with(CARTPOLE, selection_scale=3), "dagger",
                                 max_leaf_nodes=7)
    assert (got.selection_episodes, got.method, got.max_leaf_nodes) == (60, "dagger", 7)
    assert budgets.distill_config(cfg, CARTPOLE).method == "imitation-bt"
    assert budgets.distill_config(cfg, CARTPOLE, n_iterations=2).n_iterations == 2


@pytest.mark.parametrize("selection, expected", [(100, 20), (20, 20), (21, 20), (19, 19), (3, 3)])
def test_a_box_distillation_selects_on_at_most_twenty_episodes(selection, expected):
    cfg = replace(PAPER, selection_episodes=selection)
    got = budgets.box_config(cfg, PENDULUM, "dagger", None)
    assert got.selection_episodes == expected and budgets.BOX_SELECTION_EPISODES == 20


def test_a_box_distillation_takes_the_leaf_limit_and_shrinks_under_smoke():
    paper = budgets.box_config(PAPER, PENDULUM, "dagger", None)
    assert paper.max_leaf_nodes == PENDULUM.budget.max_leaf_nodes and paper.method == "dagger"
    assert budgets.box_config(PAPER, PENDULUM, "imitation-bt", 9).max_leaf_nodes == 9
    smoke = budgets.box_config(SMOKE, PENDULUM, "dagger", 9)
    assert (smoke.n_iterations, smoke.labels_per_iteration, smoke.eval_envs) == (2, 300, 3)
    assert (paper.n_iterations, paper.labels_per_iteration) != (2, 300)
    assert paper.eval_envs != 3


def test_the_relational_learners_settings_are_plain_data():
    params = budgets.learner_params()
    assert set(params) == {"weights", "margin", "max_bins"}
    assert budgets.RELATIONAL == "imitation-bt+rel" and budgets.COMMAND_TOLERANCE == 0.01


# -- refine -------------------------------------------------------------------------------

def test_a_refinement_is_the_tasks_under_paper_and_seconds_under_smoke():
    task = replace(CARTPOLE, refine=RefineConfig(episodes=5_000))
    assert budgets.refine_config(PAPER, task) == RefineConfig(episodes=5_000)
    assert budgets.refine_config(PAPER, task, max_leaves=4).max_leaves == 4
    smoke = budgets.refine_config(SMOKE, task)
    assert smoke == replace(RefineConfig(), episodes=240, **budgets.SMOKE_REFINE)
    small = replace(CARTPOLE, refine=RefineConfig(episodes=100))
    assert budgets.refine_config(SMOKE, small).episodes == 100  # never more than the task's
    assert budgets.refine_config(SMOKE, replace(CARTPOLE, refine=RefineConfig(episodes=241))
                                 ).episodes == 240


def test_the_smoke_refinement_runs_in_seconds():
    """Its CMA-ES generations, population and episodes, its sweeps, its selection: a few each."""
    smoke = budgets.SMOKE_REFINE
    assert smoke == {"cma_generations": 2, "cma_episodes": 2, "cma_popsize": 4,
                     "sweep_episodes": 2, "sweep_rounds": 1, "selection_episodes": 3,
                     "n_envs": 8}


def test_a_command_tree_is_refined_by_cma_es_alone():
    both = RefineConfig(stages=("cma", "leaves", "prune", "cma"))
    assert budgets.cma_only(both).stages == ("cma", "cma")
    assert budgets.cma_only(RefineConfig(stages=("prune",))).stages == ("cma",)
    task = replace(PENDULUM, refine=both)
    assert budgets.box_refine_config(PAPER, task).stages == ("cma", "cma")
    assert budgets.box_refine_config(SMOKE, task).cma_generations == 2
    got = budgets.box_refine_task_config(task, episodes=77)
    assert (got.stages, got.episodes) == (("cma", "cma"), 77)


@pytest.mark.parametrize("scale, episodes, total, generations", [
    (1.0, None, 1000, 60), (2.0, None, 2000, 120), (0.5, None, 500, 60), (1.5, None, 1500, 90),
    (0.001, None, 10, 60), (0.011, None, 11, 60), (1.0, 3000, 3000, 180), (1.0, 1001, 1001, 61)])
def test_a_scaled_refinement_grows_its_generations_with_its_episodes(scale, episodes, total,
                                                                     generations):
    task = replace(CARTPOLE, refine=RefineConfig(episodes=1000, cma_generations=60,
                                                 stages=("cma", "prune")))
    got = budgets.scaled_refine_config(PAPER, task, scale, episodes)
    assert (got.episodes, got.cma_generations) == (total, generations)
    assert got.stages == ("cma", "prune")
    assert budgets.scaled_refine_config(PAPER, task, scale, episodes, commands=True).stages == (
        "cma",)
    assert math.ceil(60 * total / 1000) <= got.cma_generations


# -- structure search ---------------------------------------------------------------------

def test_a_search_takes_the_tasks_budget_at_the_leaf_limit_and_shrinks_under_smoke():
    task = replace(CARTPOLE, evolve=EvolveConfig(episodes=9_000, mu=5))
    got = budgets.evolve_config(PAPER, task, 7)
    assert got == EvolveConfig(episodes=9_000, mu=5, max_leaves=7)
    assert budgets.evolve_config(PAPER, replace(task, evolve=None), 3) == EvolveConfig(
        max_leaves=3)
    assert budgets.evolve_config(PAPER, task, 7, use_expert=False).use_expert is False
    assert budgets.evolve_config(PAPER, task, 7).use_expert is True
    smoke = budgets.evolve_config(SMOKE, task, 7, use_expert=False)
    assert smoke == EvolveConfig(max_leaves=7, use_expert=False, episodes=240, mu=2, lam=4,
                                 generation_episodes=2, pool_episodes=2, selection_episodes=3,
                                 finalists=3, n_envs=8, refine_episodes=60)


def test_a_relational_search_takes_its_episodes_unless_smoke_and_refuses_less_than_a_generation():
    task = replace(CARTPOLE, evolve=EvolveConfig(episodes=9_000, generation_episodes=12))
    got = budgets.relational_search_config(PAPER, task, 5, 1234, "score")
    assert (got.episodes, got.max_leaves, got.leaf_rule) == (1234, 5, "score")
    assert budgets.relational_search_config(PAPER, task, 5).episodes == 9_000
    assert budgets.relational_search_config(PAPER, task, 5).leaf_rule == "vote"
    assert budgets.relational_search_config(PAPER, task, 5, 12).episodes == 12
    with pytest.raises(ValueError, match="11 episodes is below one generation \\(12\\)"):
        budgets.relational_search_config(PAPER, task, 5, 11)
    assert budgets.relational_search_config(SMOKE, task, 5, 1234).episodes == 240
    assert budgets.relational_search_config(SMOKE, task, 5, 1).episodes == 240


@pytest.mark.parametrize("scale, expected", [
    (1.0, 9_000), (2.0, 18_000), (0.5, 4_500), (0.01, 90), (0.001, 4 * 10 + 7),
    (0.0047, 47), (0.0048, 47), (0.0053, 48)])
def test_a_scaled_search_keeps_one_generation_and_its_pool(scale, expected):
    task = replace(CARTPOLE, evolve=EvolveConfig(episodes=9_000, mu=1, lam=3,
                                                 generation_episodes=10, pool_episodes=7))
    assert budgets.search_config(PAPER, task, 5, scale).episodes == expected
    assert budgets.search_config(PAPER, task, 5, scale).max_leaves == 5
    assert budgets.search_config(SMOKE, task, 5, scale).episodes == 240


def test_a_polish_is_cma_es_then_pruning_under_the_searchs_leaf_limit():
    search = EvolveConfig(max_leaves=6, refine_episodes=3_000, selection_episodes=40)
    assert budgets.polish_config(PAPER, search) == RefineConfig(
        stages=("cma", "prune"), episodes=3_000, cma_generations=400, cma_episodes=16,
        max_leaves=6, selection_episodes=40)
    assert budgets.polish_config(SMOKE, search) == RefineConfig(
        stages=("cma", "prune"), episodes=3_000, max_leaves=6, **budgets.SMOKE_REFINE)


def test_a_polish_again_runs_twice_the_polish_episodes():
    task = replace(CARTPOLE, evolve=EvolveConfig(episodes=9_000, refine_episodes=3_000))
    again = budgets.again_config(PAPER, task, 4, 1.0)
    assert budgets.AGAIN_FACTOR == 2
    assert again == replace(budgets.polish_config(PAPER, budgets.search_config(PAPER, task, 4,
                                                                                1.0)),
                            episodes=6_000)
    assert again.max_leaves == 4


def test_a_profile_named_at_run_time_is_the_profile_of_that_name():
    """``IBT_PROFILE=smoke`` (as CI sets it) names the profile with a string made at run time,
    equal to the literal but not the same object: every builder shrinks alike."""
    profile = "".join(["sm", "oke"])
    cfg = replace(SMOKE, profile=profile)
    task = replace(CARTPOLE, evolve=EvolveConfig(episodes=9_000), refine=RefineConfig())
    assert budgets.evolve_config(cfg, task, 5) == budgets.evolve_config(SMOKE, task, 5)
    assert budgets.refine_config(cfg, task) == budgets.refine_config(SMOKE, task)
    assert budgets.box_config(cfg, PENDULUM, "dagger", 4) == budgets.box_config(
        SMOKE, PENDULUM, "dagger", 4)
    assert budgets.relational_search_config(cfg, task, 5, 1234).episodes == 240
    assert budgets.search_config(cfg, task, 5, 0.5).episodes == 240
    search = budgets.search_config(SMOKE, task, 5, 1.0)
    assert budgets.polish_config(cfg, search) == budgets.polish_config(SMOKE, search)
