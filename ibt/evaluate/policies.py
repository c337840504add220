"""Policies: anything with ``act(obs_batch) -> actions`` on raw observations.

Experts (:class:`ibt.experts.expert.Expert`) satisfy the protocol directly; this module adapts
decision
trees and behavior trees to it, mapping raw observations to the task's features first. The tree
policy uses a compiled NumPy traversal instead of ``DecisionTreeClassifier.predict`` (identical
decisions, without scikit-learn's per-call validation overhead, which dominates in rollouts).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.executors import as_features
from ibt.bt.model import NO_DECISION, BehaviorTree
from ibt.tasks.catalogue import Task


class Policy(Protocol):
    def act(self, obs: np.ndarray) -> np.ndarray: ...


SMALL_BATCH = 64


class CompiledTree:
    """A fitted CART tree as flat arrays; ``predict`` equals scikit-learn's on every input.

    A relational tree (:class:`ibt.distill.relational.RelationalTreeClassifier`) takes
    observed features too: its derived columns are appended first (its ``feature_map_``)."""

    def __init__(self, tree: DecisionTreeClassifier) -> None:
        self.feature_map = getattr(tree, "feature_map_", None)
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
        if self.feature_map is not None:
            features = self.feature_map.augment(np.atleast_2d(features))
        x = as_features(np.atleast_2d(features))
        if len(x) <= SMALL_BATCH:  # a rollout's few rows: walking in Python beats array passes
            return self._predict_rows(x)
        rows = np.arange(len(x))
        node = np.zeros(len(x), dtype=np.intp)
        for _ in range(self.depth):
            go_left = x[rows, self.feature[node]] <= self.threshold[node]
            nxt = np.where(go_left, self.left[node], self.right[node])
            node = np.where(self.is_leaf[node], node, nxt)
        return self.leaf_action[node]

    def _predict_rows(self, x: np.ndarray) -> np.ndarray:
        if not hasattr(self, "_lists"):  # the same float64 comparisons as the vector path
            self._lists = (self.feature.tolist(), self.threshold.tolist(), self.left.tolist(),
                           self.right.tolist(), self.is_leaf.tolist())
        feature, threshold, left, right, is_leaf = self._lists
        out = np.empty(len(x), dtype=np.int64)
        for i, row in enumerate(x.tolist()):
            node = 0
            while not is_leaf[node]:
                node = left[node] if row[feature[node]] <= threshold[node] else right[node]
            out[i] = self.leaf_action[node]
        return out


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
        decisions = self.bt.decide(self.task.features(obs))
        if (decisions == NO_DECISION).any():  # never send "no action" to the environment
            row = int(np.argmax(decisions == NO_DECISION))
            raise RuntimeError(f"the BT reaches no action on the observation "
                               f"{np.asarray(obs)[row].tolist()}; bt.validate() says why")
        return decisions


class RandomPolicy:
    """Uniformly random actions from a seeded generator."""

    def __init__(self, n_actions: int, seed: int = 0) -> None:
        self.n_actions = n_actions
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.integers(0, self.n_actions, size=len(obs))
