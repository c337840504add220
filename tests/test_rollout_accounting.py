"""What a rollout counts: its budget is in environment steps (one per row of a batch, not one
per batch), episodes start only while the budget lasts and always finish; the outcome rates
of ``episode_metrics`` are means over episodes, NaN over none."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ibt.evaluate.rollouts import METRIC_FUNCTIONS, Rollout, episode_metrics, rollout
from ibt.tasks.catalogue import get_task

CARTPOLE = get_task("CartPole-v1")


def test_the_budget_counts_steps_and_stops_only_starting_episodes():
    """Mutants: ``steps += len(active)`` counting batches, ``steps >= budget`` as ``>`` (an
    episode started on a budget spent exactly), or the budget test dropped."""
    budget, n_envs = 25, 3
    batch_sizes: list[int] = []
    started_at: dict[int, int] = {}

    def push_left(obs, episodes):  # every CartPole episode falls within a dozen steps
        for e in episodes.tolist():
            started_at.setdefault(e, sum(batch_sizes))
        batch_sizes.append(len(obs))
        return np.zeros(len(obs), dtype=np.int64)

    result = rollout(CARTPOLE, push_left, range(40), n_envs=n_envs, budget=budget, indexed=True)
    assert len(result.returns) == len(started_at) < 40
    assert all(steps < budget for steps in started_at.values())
    assert sum(batch_sizes) == int(result.lengths.sum()) >= budget
    assert sorted(started_at) == list(range(len(result.returns)))
    assert np.all(result.lengths > 0)  # every started episode ran to its end
    # a budget spent exactly by the first episode starts no second one
    first = rollout(CARTPOLE, push_left, [0], n_envs=1, indexed=True)
    exact = int(first.lengths[0])
    spent = rollout(CARTPOLE, push_left, [0, 1, 2], n_envs=1, budget=exact, indexed=True)
    assert spent.lengths.tolist() == [exact]
    assert len(rollout(CARTPOLE, push_left, [0, 1, 2], n_envs=1, budget=exact + 1,
                       indexed=True).returns) == 2
    unlimited = rollout(CARTPOLE, lambda obs: np.zeros(len(obs), dtype=np.int64), range(5),
                        n_envs=2)
    assert len(unlimited.returns) == 5


def _rollout() -> Rollout:
    return Rollout(returns=np.array([1.0, -2.0, 3.0, 0.0]), lengths=np.array([5, 6, 7, 8]),
                   final_infos=[{"crashed": True}, {},
                                {"battery_failure": 1, "delivered_heavy": 2},
                                {"delivered_light": 1}],
                   terminated=np.array([True, False, True, True]))


@pytest.mark.parametrize(("metric", "column", "value"), [
    ("success_if_positive", "success_rate", 0.5),
    ("success_if_terminated", "success_rate", 0.75),
    ("collision_rate", "collision_rate", 0.25),
    ("battery_failure_rate", "battery_failure_rate", 0.25),
    ("delivered", "delivered", 0.75),
])
def test_each_outcome_rate_is_a_mean_over_episodes(metric, column, value):
    task = replace(CARTPOLE, metrics=(metric,))
    assert episode_metrics(task, _rollout()) == {column: value}
    empty = Rollout(np.zeros(0), np.zeros(0, dtype=np.int64), [], np.zeros(0, dtype=bool))
    assert math.isnan(episode_metrics(task, empty)[column])


def test_every_metric_is_measured_and_an_unknown_one_is_named():
    assert {name for name, _ in METRIC_FUNCTIONS.items()} == {
        "success_if_positive", "success_if_terminated", "collision_rate",
        "battery_failure_rate", "delivered"}
    both = replace(CARTPOLE, metrics=("collision_rate", "delivered"))
    assert episode_metrics(both, _rollout()) == {"collision_rate": 0.25, "delivered": 0.75}
    with pytest.raises(ValueError, match="unknown metric 'nope'; known: success_if_positive"):
        episode_metrics(replace(CARTPOLE, metrics=("nope",)), _rollout())
