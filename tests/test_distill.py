"""The interactive loop: schedules, mixing, weights, method table, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from ibt.distill import schedules
from ibt.distill.loop import METHODS, DistillConfig, _signature, distill, mix
from ibt.evaluate.rollouts import final_seeds, rollout, selection_seeds
from ibt.tasks.catalogue import get_task


def test_schedule_values_are_exact():
    assert schedules.linear().values(4) == [1.0, 0.75, 0.5, 0.25]
    assert schedules.exponential(0.5).values(4) == [1.0, 0.5, 0.25, 0.125]
    assert schedules.exponential(0.1).values(3) == pytest.approx([1.0, 0.1, 0.01])
    assert schedules.constant(1.0).values(3) == [1.0, 1.0, 1.0]
    assert schedules.first_only().values(3) == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="outside"):
        schedules.linear()(5, 5)
    with pytest.raises(ValueError, match="unknown schedule"):
        schedules.Schedule("cosine")


def test_methods_differ_exactly_as_documented():
    assert METHODS["bc"].schedule == schedules.constant(1)
    assert not METHODS["bc"].weighted and not METHODS["dagger"].weighted
    assert METHODS["dagger"].schedule == schedules.exponential(0.5)
    assert METHODS["viper"].schedule == schedules.first_only() and METHODS["viper"].weighted
    assert METHODS["imitation-bt"].schedule == schedules.linear()
    assert METHODS["imitation-bt"].weighted


def test_seed_sets_are_disjoint():
    final = set(final_seeds(1000))
    chosen = set(selection_seeds(1000, 0)) | set(selection_seeds(1000, 4))
    assert not final & chosen


def test_expert_weights_are_the_score_gap(cartpole_expert):
    obs = np.array([[0.0, 0.0, 0.05, 0.0], [0.0, 0.0, -0.05, 0.0]], dtype=np.float32)
    actions, weights = cartpole_expert.label(obs)
    scores = cartpole_expert.scores(obs)
    assert scores.shape == (2, 2)
    assert np.allclose(np.exp(scores).sum(axis=1), 1.0)  # log pi for PPO
    assert np.allclose(weights, scores.max(1) - scores.min(1))
    assert actions.tolist() == [1, 0]  # push towards the falling side


@pytest.mark.parametrize("beta", [0.0, 0.1, 0.5, 0.9, 1.0])
def test_mixed_policy_uses_the_expert_with_frequency_beta(beta):
    rng = np.random.default_rng(0)
    n = 20_000
    expert, learner = np.ones(n, int), np.zeros(n, int)
    share = mix(expert, learner, beta, rng).mean()
    # binomial standard error at n = 20,000 is <= 0.0036; allow 4 of them
    assert abs(share - beta) <= 0.015


def test_same_seed_same_tree_and_different_seed_differs(cartpole_expert):
    cfg = DistillConfig.for_task(get_task("CartPole-v1"), n_iterations=3, labels_per_iteration=300,
                                 selection_episodes=2)
    a = distill(get_task("CartPole-v1"), cartpole_expert, cfg, seed=1, progress=False)
    b = distill(get_task("CartPole-v1"), cartpole_expert, cfg, seed=1, progress=False)
    c = distill(get_task("CartPole-v1"), cartpole_expert, cfg, seed=2, progress=False)
    assert [_signature(t) for t in a.trees] == [_signature(t) for t in b.trees]
    assert a.iterations == b.iterations
    assert [_signature(t) for t in a.trees] != [_signature(t) for t in c.trees]


def test_weighted_resampling_changes_the_fit(cartpole_expert):
    common = {"n_iterations": 2, "labels_per_iteration": 400, "selection_episodes": 1}
    viper = distill(get_task("CartPole-v1"), cartpole_expert,
                    DistillConfig.for_task(get_task("CartPole-v1"), method="viper", **common),
                    seed=0,
                    progress=False)
    bc = distill(get_task("CartPole-v1"), cartpole_expert,
                 DistillConfig.for_task(get_task("CartPole-v1"), method="bc", **common), seed=0,
                 progress=False)
    # iteration 0 sees the same expert episodes; only the resampling differs
    assert viper.iterations[0]["labels"] == bc.iterations[0]["labels"]
    assert _signature(viper.trees[0]) != _signature(bc.trees[0])


def test_successive_rollouts_differ_after_loading(cartpole_expert):
    """SB3's load() reseeds global RNGs; our episodes are seeded explicitly and must differ."""
    first = rollout(get_task("CartPole-v1"), cartpole_expert.act, [11], collect=True)
    second = rollout(get_task("CartPole-v1"), cartpole_expert.act, [12], collect=True)
    again = rollout(get_task("CartPole-v1"), cartpole_expert.act, [11], collect=True)
    assert not np.array_equal(first.obs[0], second.obs[0])
    assert np.array_equal(first.obs[0], again.obs[0])


def test_budget_runs_whole_episodes():
    result = rollout(get_task("CartPole-v1"), lambda obs: np.zeros(len(obs), int), range(100),
                     n_envs=2,
                     budget=50)
    assert result.lengths.sum() >= 50
    assert len(result.returns) < 100
    assert all(result.terminated | (result.lengths == 500))


def test_task_budgets_scale_the_profile_settings_alike_for_every_method():
    import ibt
    from ibt.runs.steps import distill_config

    paper = ibt.config("paper")
    for method in METHODS:
        assert distill_config(paper, "CartPole-v1", method).selection_episodes == 20
        delivery = distill_config(paper, "PackageDelivery-v0", method)
        assert delivery.selection_episodes == 100 and delivery.max_leaf_nodes == 32
        assert distill_config(paper, "highway-fast-v0", method).n_iterations == 10
    smoke = ibt.config("smoke")
    assert distill_config(smoke, "PackageDelivery-v0").selection_episodes == 15
    assert distill_config(paper, "PackageDelivery-v0", selection_episodes=7
                          ).selection_episodes == 7
