"""The structure search's mutations: one random edit of a small tree, helped by the expert.

The structure search by return (:mod:`ibt.refine.structure`) makes each generation's children
by one mutation of a parent. Mutations edit the tree as nested tuples (``("leaf", action)`` or
``("split", feature, threshold, left, right)``, :func:`nested` and :func:`arrays` convert), and
draw every choice from the search's own generator, so a search is deterministic in its seed:

* **mutations**: move one threshold (in units of its feature's spread over visited states),
  move all thresholds a little, change a split's feature (a new threshold drawn from visited
  states), change a leaf's action, replace a subtree by a leaf, grow a leaf into a split.
* **the expert's help** (optional): a pool of states the current best tree visits is labelled
  by the expert (DAgger's labels, on the small tree's own state distribution); "grow" then
  fits the split that best separates the expert's labels among the pool states reaching the
  leaf (a CART stump), and "relabel" gives a leaf the expert's majority action there.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.refine.tree_arrays import TreeArrays, tree_arrays_from_nested
from ibt.tasks.settings import EvolveConfig
from ibt.tasks.task import Task

MUTATIONS = ("threshold", "thresholds", "feature", "action", "prune", "grow", "relabel")


# --- trees as nested tuples: ("leaf", action) or ("split", feature, threshold, left, right) ---

def nested(tree: TreeArrays, node: int = 0) -> tuple:
    """The subtree at ``node`` as nested tuples (what a mutation edits)."""
    if tree.is_leaf[node]:
        return ("leaf", int(tree.action[node]))
    return ("split", int(tree.feature[node]), float(tree.threshold[node]),
            nested(tree, int(tree.left[node])), nested(tree, int(tree.right[node])))


def arrays(node: tuple, n_features: int, n_actions: int) -> TreeArrays:
    """Nested tuples back to a simplified :class:`TreeArrays` (what the search scores)."""
    def weighted(n: tuple) -> tuple:
        if n[0] == "leaf":
            return ("leaf", n[1], 1.0)
        return ("split", n[1], n[2], weighted(n[3]), weighted(n[4]), 1.0)

    return tree_arrays_from_nested(weighted(node), n_features, n_actions).simplified()


def _paths(node: tuple, path: tuple = ()) -> list[tuple[tuple, tuple]]:
    """Every (path, subtree); a path is a tuple of 3 (left) / 4 (right) child positions."""
    out = [(path, node)]
    if node[0] == "split":
        out += _paths(node[3], (*path, 3)) + _paths(node[4], (*path, 4))
    return out


def _replace(node: tuple, path: tuple, new: tuple) -> tuple:
    if not path:
        return new
    head, rest = path[0], path[1:]
    parts = list(node)
    parts[head] = _replace(node[head], rest, new)
    return tuple(parts)


def _leaves(node: tuple) -> int:
    return 1 if node[0] == "leaf" else _leaves(node[3]) + _leaves(node[4])


class TreeMutator:
    """One random mutation of a tree, with the visited-state pool and the expert's labels."""

    def __init__(self, task: Task, config: EvolveConfig, rng: np.random.Generator,
                 expert: Any | None) -> None:
        self.task, self.config, self.rng, self.expert = task, config, rng, expert
        self.pool = np.zeros((0, task.n_features), dtype=np.float32)
        self.labels = np.zeros(0, dtype=np.int64)
        self.scores = np.zeros((0, task.n_actions))  # the expert's, where leaf_rule is "score"
        self.spread = np.ones(task.n_features)

    def refresh(self, states: np.ndarray) -> None:
        keep = self.rng.permutation(len(states))[:4000]
        self.pool = states[keep]
        box = np.asarray(self.task.high, float) - np.asarray(self.task.low, float)
        floor = np.where(np.isfinite(box) & (box > 0), 1e-3 * box, 1e-3)
        self.spread = np.maximum(self.pool.astype(np.float64).std(axis=0), floor)
        if self.expert is not None and self.config.use_expert:
            observed = self.task.observations(self.pool)
            if self.config.leaf_rule == "score":
                self.scores = np.asarray(self.expert.scores(observed), dtype=np.float64)
                self.labels = np.argmax(self.scores, axis=1).astype(np.int64)
            else:
                self.labels = np.asarray(self.expert.act(observed), dtype=np.int64)

    def _leaf_action(self, mask: np.ndarray) -> int:
        """The expert's action for the pool states in ``mask`` (at least one): the majority of
        its labels ("vote") or the highest mean score ("score": the best single action for
        the region by the expert's own values)."""
        if self.config.leaf_rule == "score":
            return int(np.argmax(self.scores[mask].mean(axis=0)))
        return int(np.argmax(np.bincount(self.labels[mask], minlength=self.task.n_actions)))

    def _reaching(self, root: tuple, path: tuple) -> np.ndarray:
        mask = np.ones(len(self.pool), dtype=bool)
        node = root
        for step in path:
            go_left = self.pool[:, node[1]].astype(np.float64) <= node[2]
            mask &= go_left if step == 3 else ~go_left
            node = node[step]
        return mask

    def _threshold_from_pool(self, feature: int, mask: np.ndarray | None = None) -> float:
        values = self.pool[mask if mask is not None and mask.any() else slice(None), feature]
        if len(values) == 0:
            lo, hi = self.task.low[feature], self.task.high[feature]
            return float(self.rng.uniform(lo, hi))
        return float(values[self.rng.integers(len(values))])

    def _stump(self, root: tuple, path: tuple, leaf: tuple) -> tuple | None:
        """The split that best separates the expert's labels among the pool states reaching
        the leaf (CART's Gini), with the majority label on each side."""
        mask = self._reaching(root, path)
        if mask.sum() < 10 or len(self.labels) != len(self.pool):
            return None
        stump = DecisionTreeClassifier(max_depth=1, random_state=0)
        weight = None
        if self.config.leaf_rule == "score":
            scores = self.scores[mask]
            weight = scores.max(axis=1) - scores.min(axis=1) + 1e-12
        stump.fit(self.pool[mask], self.labels[mask], sample_weight=weight)
        t = stump.tree_
        if t.node_count < 3:
            return None
        feature, threshold = int(t.feature[0]), float(t.threshold[0])
        if self.config.leaf_rule == "score":
            go_left = self.pool[:, feature].astype(np.float64) <= threshold
            left = ("leaf", self._leaf_action(mask & go_left))
            right = ("leaf", self._leaf_action(mask & ~go_left))
        else:
            classes = stump.classes_
            left = ("leaf", int(classes[int(np.argmax(t.value[1, 0]))]))
            right = ("leaf", int(classes[int(np.argmax(t.value[2, 0]))]))
        if left[1] == right[1]:
            return None
        return ("split", feature, threshold, left, right)

    def mutate(self, root: tuple) -> tuple:
        kind = MUTATIONS[int(self.rng.integers(len(MUTATIONS)))]
        if kind == "relabel" and (self.expert is None or not self.config.use_expert):
            kind = "action"
        nodes = _paths(root)
        splits = [(p, n) for p, n in nodes if n[0] == "split"]
        leaves = [(p, n) for p, n in nodes if n[0] == "leaf"]
        n_actions = self.task.n_actions
        if kind in ("threshold", "feature", "thresholds", "prune") and not splits:
            kind = "grow"
        if kind == "threshold":
            path, node = splits[int(self.rng.integers(len(splits)))]
            step = self.rng.normal(0, self.config.sigma) * self.spread[node[1]]
            return _replace(root, path, ("split", node[1], node[2] + step, node[3], node[4]))
        if kind == "thresholds":
            out = root
            for path, node in splits:
                current = dict(_paths(out))[path]
                step = self.rng.normal(0, self.config.sigma / 4) * self.spread[node[1]]
                out = _replace(out, path, ("split", current[1], current[2] + step,
                                           current[3], current[4]))
            return out
        if kind == "feature":
            path, node = splits[int(self.rng.integers(len(splits)))]
            feature = int(self.rng.integers(self.task.n_features))
            threshold = self._threshold_from_pool(feature, self._reaching(root, path))
            return _replace(root, path, ("split", feature, threshold, node[3], node[4]))
        if kind == "action":
            path, node = leaves[int(self.rng.integers(len(leaves)))]
            action = int(self.rng.integers(n_actions - 1))
            action += action >= node[1]
            return _replace(root, path, ("leaf", action))
        if kind == "prune":
            path, node = splits[int(self.rng.integers(len(splits)))]
            keep = node[3] if self.rng.random() < 0.5 else node[4]
            return _replace(root, path, keep)
        if kind == "relabel":
            path, node = leaves[int(self.rng.integers(len(leaves)))]
            mask = self._reaching(root, path)
            if not mask.any():
                return self.mutate(root)
            return _replace(root, path, ("leaf", self._leaf_action(mask)))
        # grow
        if _leaves(root) >= self.config.max_leaves:
            return self._grow_or_prune(root)
        return self._grow(root, leaves)

    def _grow(self, root: tuple, leaves: list[tuple[tuple, tuple]]) -> tuple:
        path, node = leaves[int(self.rng.integers(len(leaves)))]
        if self.expert is not None and self.config.use_expert and self.rng.random() < 0.7:
            stump = self._stump(root, path, node)
            if stump is not None:
                return _replace(root, path, stump)
        feature = int(self.rng.integers(self.task.n_features))
        threshold = self._threshold_from_pool(feature, self._reaching(root, path))
        other = int(self.rng.integers(self.task.n_actions))
        children = (node, ("leaf", other)) if self.rng.random() < 0.5 else (("leaf", other), node)
        return _replace(root, path, ("split", feature, threshold, *children))

    def _grow_or_prune(self, root: tuple) -> tuple:
        """At the leaf limit, growth must pay for itself: cut a random subtree, then grow."""
        splits = [(p, n) for p, n in _paths(root) if n[0] == "split"]
        path, node = splits[int(self.rng.integers(len(splits)))]
        cut = _replace(root, path, node[3] if self.rng.random() < 0.5 else node[4])
        leaves = [(p, n) for p, n in _paths(cut) if n[0] == "leaf"]
        return self._grow(cut, leaves)


__all__ = ["MUTATIONS", "arrays", "nested"]
