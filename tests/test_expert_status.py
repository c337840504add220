"""Experts that count: below the bar is excluded, one action on every step is constant-action."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from ibt.experts import training
from ibt.tasks.catalogue import get_task


def _fake_expert(monkeypatch, act):
    monkeypatch.setattr(training, "load_expert",
                        lambda task, algo, path=None: SimpleNamespace(act=act, n_actions=4))


def test_a_constant_expert_is_detected(monkeypatch):
    _fake_expert(monkeypatch, lambda obs: np.full(len(obs), 1))
    # Expect: every step 'right' on CliffWalking (the episodes never end: 100-step limit)
    status = training.expert_status(get_task("CliffWalking-v1"), "dqn", True, n_episodes=3)
    assert status["status"] == "constant-action"
    assert status["status_evidence"] == "always 'right' on all 300 steps of the 3 final episodes"


def test_below_the_bar_is_excluded_whatever_it_does(monkeypatch):
    _fake_expert(monkeypatch, lambda obs: np.full(len(obs), 1))
    status = training.expert_status(get_task("CliffWalking-v1"), "dqn", False, n_episodes=2)
    assert status["status"] == "excluded"
    assert status["status_evidence"].startswith("below its bar; actions over the 2 final")


def test_a_committed_expert_is_ok_with_its_action_counts():
    counts, steps = training.action_counts(get_task("FrozenLake-v1"), "dqn", n_episodes=4)
    assert steps == 24 and counts == {1: 12, 2: 12}  # down and right, 6 steps an episode
    status = training.expert_status(get_task("FrozenLake-v1"), "dqn", True, n_episodes=4)
    assert status == {"status": "ok", "status_evidence":
                      "actions over the 4 final episodes (24 steps): down 12, right 12"}


def test_statuses_are_read_from_the_manifest(tmp_path):
    pd.DataFrame([{"task": "CartPole-v1", "algo": "dqn", "status": "constant-action",
                   "meets_bar": True},
                  {"task": "CartPole-v1", "algo": "ppo", "status": np.nan, "meets_bar": True},
                  {"task": "CartPole-v1", "algo": "a2c", "status": np.nan, "meets_bar": False},
                  ]).to_csv(tmp_path / "manifest.csv", index=False)
    assert training.expert_statuses(tmp_path) == {("CartPole-v1", "dqn"): "constant-action",
                                                  ("CartPole-v1", "ppo"): "ok",
                                                  ("CartPole-v1", "a2c"): "excluded"}
