"""Shared fixtures: small fitted trees on synthetic data, and the committed CartPole expert."""

from __future__ import annotations

import os
from dataclasses import replace

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


@pytest.fixture(scope="session")
def agents(tmp_path_factory):
    """A small PPO checkpoint for each toy task of the pipeline tests (seconds; quality does
    not matter here)."""
    import importlib

    for module in ("tests.fixtures.toy_line", "tests.fixtures.toy_cart"):  # the users' modules
        importlib.import_module(module)
    from ibt.experts.expert import train_expert
    from ibt.tasks.catalogue import resolve_task
    from ibt.tasks.settings import hp

    root = tmp_path_factory.mktemp("agents")
    line = replace(resolve_task("ToyLine-v0"),
                   experts=(("ppo", hp(1024, 1, n_steps=256, batch_size=64, gamma=0.9)),))
    train_expert(line, "ppo", root / "line.zip", progress=False)
    train_expert(resolve_task("ToyCart-v0"), "ppo", root / "cart.zip", timesteps=2048,
                 progress=False)
    return root
