"""Committed experts load, answer with scores of shape (batch, n_actions), and are recorded."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ibt.experts import HYPERPARAMS, expert_path, load_expert
from ibt.paths import DATA_DIR
from ibt.tasks import TASKS, get_task

MANIFEST = pd.read_csv(DATA_DIR / "experts" / "manifest.csv")
COMMITTED = [(t, a) for t, a in zip(MANIFEST.task, MANIFEST.algo, strict=True)
             if expert_path(t, a).exists()]


def test_every_task_and_algo_has_hyperparameters():
    assert {(t, a) for t in TASKS for a in ("dqn", "ppo", "a2c")} <= set(HYPERPARAMS)


def test_manifest_has_the_required_columns():
    required = {"task", "algo", "timesteps", "seed", "mean_return", "std_return", "n_episodes",
                "wall_seconds"}
    assert required <= set(MANIFEST.columns)
    assert (MANIFEST.n_episodes == 100).all()


@pytest.mark.parametrize(("task", "algo"), COMMITTED)
def test_committed_expert_scores(task, algo):
    expert = load_expert(task, algo)
    spec = get_task(task)
    env = spec.make_env()
    obs = np.stack([env.reset(seed=s)[0] for s in range(5)])
    scores = expert.scores(obs)
    assert scores.shape == (5, spec.n_actions)
    assert np.isfinite(scores).all()
    if algo != "dqn":  # log-probabilities
        assert np.allclose(np.exp(scores).sum(axis=1), 1.0, atol=1e-5)
    assert np.array_equal(expert.act(obs), scores.argmax(axis=1))


def test_random_baselines_cover_every_task():
    random = pd.read_csv(DATA_DIR / "experts" / "random.csv")
    assert set(TASKS) <= set(random.task)
    for name in TASKS:
        assert np.isfinite(get_task(name).random_return())
