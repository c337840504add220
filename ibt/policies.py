"""Policies: anything with ``act(obs_batch) -> actions`` on raw observations.

Experts (:class:`ibt.experts.Expert`) satisfy the protocol directly; this module adapts decision
trees and behavior trees to it, mapping raw observations to the task's features first. The tree
policy uses a compiled NumPy traversal instead of ``DecisionTreeClassifier.predict`` (identical
decisions, without scikit-learn's per-call validation overhead, which dominates in rollouts).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.bt import BehaviorTree, as_features
from ibt.tasks import Task


class Policy(Protocol):
    def act(self, obs: np.ndarray) -> np.ndarray: ...


class CompiledTree:
    """A fitted CART tree as flat arrays; ``predict`` equals scikit-learn's on every input."""

    def __init__(self, tree: DecisionTreeClassifier) -> None:
        t = tree.tree_
        self.feature = np.where(t.feature >= 0, t.feature, 0).astype(np.intp)
        self.threshold = t.threshold.astype(np.float64)
        self.left = t.children_left.astype(np.intp)
        self.right = t.children_right.astype(np.intp)
        self.is_leaf = self.left == self.right
        classes = np.asarray(tree.classes_)
        self.leaf_action = classes[np.argmax(t.value[:, 0, :], axis=1)].astype(np.int64)
        self.depth = int(tree.get_depth())

    def predict(self, features: np.ndarray) -> np.ndarray:
        x = as_features(np.atleast_2d(features))
        rows = np.arange(len(x))
        node = np.zeros(len(x), dtype=np.intp)
        for _ in range(self.depth):
            go_left = x[rows, self.feature[node]] <= self.threshold[node]
            nxt = np.where(go_left, self.left[node], self.right[node])
            node = np.where(self.is_leaf[node], node, nxt)
        return self.leaf_action[node]


class TreePolicy:
    """A decision tree acting on raw observations of ``task``."""

    def __init__(self, task: Task, tree: DecisionTreeClassifier) -> None:
        self.task = task
        self.tree = tree
        self._compiled = CompiledTree(tree)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self._compiled.predict(self.task.features(obs))


class BTPolicy:
    """A behavior tree acting on raw observations of ``task``."""

    def __init__(self, task: Task, bt: BehaviorTree) -> None:
        self.task = task
        self.bt = bt

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.bt.decide(self.task.features(obs))


class RandomPolicy:
    """Uniformly random actions from a seeded generator."""

    def __init__(self, n_actions: int, seed: int = 0) -> None:
        self.n_actions = n_actions
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.integers(0, self.n_actions, size=len(obs))
