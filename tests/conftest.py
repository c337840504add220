"""Shared fixtures: small fitted trees on synthetic data, and the committed CartPole expert."""

from __future__ import annotations

import os

import numpy as np
import pytest
from sklearn.tree import DecisionTreeClassifier

from ibt.tasks.catalogue import get_task

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("MPLBACKEND", "Agg")


def fit_tree(n_features: int = 4, n_actions: int = 3, leaves: int = 12, seed: int = 0,
             n: int = 2000) -> tuple[DecisionTreeClassifier, np.ndarray]:
    """A CART tree on a nonlinear synthetic labelling (many repeated thresholds per feature)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, size=(n, n_features)).astype(np.float32)
    score = np.sin(3 * x[:, 0]) + x[:, 1] * x[:, -1] + 0.5 * x[:, 1] ** 2
    y = np.digitize(score, np.quantile(score, np.linspace(0, 1, n_actions + 1)[1:-1]))
    tree = DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, y)
    return tree, x


@pytest.fixture(scope="session")
def cartpole_expert():
    from ibt.experts.expert import load_expert

    return load_expert(get_task("CartPole-v1"), "ppo")
