"""Axis-aligned decision trees as flat arrays, to and from scikit-learn.

Refinement (:mod:`ibt.refine.by_return`) changes a distilled tree's thresholds, leaf actions and
shape.
Everything downstream (rules, synthesis, verification, drawings, caches) reads scikit-learn's
``DecisionTreeClassifier``, so a refined tree is rebuilt as one: :class:`TreeArrays` holds the
structure (``feature``, ``threshold``, ``left``, ``right``), each node's ``action`` (used at
leaves) and each node's sample weight, and :meth:`TreeArrays.to_sklearn` writes them into a
scikit-learn tree through its own pickling state, so that ``predict``, ``tree_`` and every
function of this package see an ordinary fitted tree.

The classes of a rebuilt tree are always ``0 .. n_actions - 1`` (a leaf's value is one-hot on its
action), so a tree rebuilt from one whose ``classes_`` were a subset decides identically.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.tree import DecisionTreeClassifier
from sklearn.tree._tree import Tree

LEAF = -1  # scikit-learn's TREE_LEAF: children of a leaf
UNDEFINED = -2  # scikit-learn's TREE_UNDEFINED: feature and threshold of a leaf


@dataclass(frozen=True)
class TreeArrays:
    """A binary axis-aligned tree: node ``i`` goes left when ``x[feature[i]] <= threshold[i]``."""

    feature: np.ndarray  # int64, UNDEFINED at leaves
    threshold: np.ndarray  # float64, UNDEFINED at leaves
    left: np.ndarray  # int64, LEAF at leaves
    right: np.ndarray  # int64, LEAF at leaves
    action: np.ndarray  # int64, the decision of each leaf (internal nodes: ignored)
    samples: np.ndarray  # float64, training weight that reached each node (for tie-breaking)
    n_features: int
    n_actions: int

    @property
    def is_leaf(self) -> np.ndarray:
        return self.left == LEAF

    @property
    def n_leaves(self) -> int:
        return int(self.is_leaf.sum())

    @property
    def n_splits(self) -> int:
        return int((~self.is_leaf).sum())

    @property
    def node_count(self) -> int:
        return len(self.feature)

    @classmethod
    def from_sklearn(cls, tree: DecisionTreeClassifier) -> TreeArrays:
        """The arrays of a fitted tree, leaf actions mapped through ``classes_``."""
        t = tree.tree_
        classes = np.asarray(tree.classes_).astype(np.int64)
        action = classes[np.argmax(t.value[:, 0, :], axis=1)]
        leaf = t.children_left == LEAF
        n_actions = int(max(int(classes.max()) + 1, getattr(tree, "n_actions_", 0)))
        return cls(
            feature=np.where(leaf, UNDEFINED, t.feature).astype(np.int64),
            threshold=np.where(leaf, float(UNDEFINED), t.threshold).astype(np.float64),
            left=t.children_left.astype(np.int64), right=t.children_right.astype(np.int64),
            action=action.astype(np.int64),
            samples=t.weighted_n_node_samples.astype(np.float64),
            n_features=int(tree.n_features_in_), n_actions=n_actions)

    def with_parameters(self, threshold: np.ndarray | None = None,
                        action: np.ndarray | None = None) -> TreeArrays:
        """The same structure with other thresholds and/or leaf actions."""
        return TreeArrays(self.feature, self.threshold if threshold is None else
                          np.asarray(threshold, dtype=np.float64),
                          self.left, self.right,
                          self.action if action is None else np.asarray(action, dtype=np.int64),
                          self.samples, self.n_features, self.n_actions)

    def depth(self) -> int:
        depth = np.zeros(self.node_count, dtype=np.int64)
        for node in range(self.node_count):  # parents precede children in our layouts
            if not self.is_leaf[node]:
                depth[self.left[node]] = depth[node] + 1
                depth[self.right[node]] = depth[node] + 1
        return int(depth.max()) if self.node_count else 0

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Decisions on a batch, comparing float32 features widened to float64 (as sklearn)."""
        x = np.asarray(features, dtype=np.float32).astype(np.float64)
        node = np.zeros(len(x), dtype=np.int64)
        rows = np.arange(len(x))
        safe_feature = np.maximum(self.feature, 0)
        for _ in range(self.depth()):
            leaf = self.is_leaf[node]
            go_left = x[rows, safe_feature[node]] <= self.threshold[node]
            node = np.where(leaf, node, np.where(go_left, self.left[node], self.right[node]))
        return self.action[node]

    def simplified(self) -> TreeArrays:
        """An equivalent tree without dead splits, unreachable nodes or redundant leaves.

        Exact on every input: a split whose threshold lies outside the interval its ancestors
        leave for its feature always goes one way and is replaced by that child (this is how a
        threshold set to +-inf prunes a subtree); a split whose two children are leaves with the
        same action becomes that leaf. Nodes are renumbered depth first, left before right,
        the layout scikit-learn uses.
        """
        lo = np.full(self.n_features, -np.inf)
        hi = np.full(self.n_features, np.inf)

        def build(node: int, lo: np.ndarray, hi: np.ndarray) -> tuple:
            if self.is_leaf[node]:
                return ("leaf", int(self.action[node]), float(self.samples[node]))
            f, t = int(self.feature[node]), float(self.threshold[node])
            if t >= hi[f]:  # x <= hi <= t: always left
                return build(int(self.left[node]), lo, hi)
            if t < lo[f] or (t == lo[f]):  # x > lo >= t: always right
                return build(int(self.right[node]), lo, hi)
            hi_left = hi.copy()
            hi_left[f] = t
            lo_right = lo.copy()
            lo_right[f] = t
            left = build(int(self.left[node]), lo, hi_left)
            right = build(int(self.right[node]), lo_right, hi)
            if left[0] == "leaf" and right[0] == "leaf" and left[1] == right[1]:
                return ("leaf", left[1], left[2] + right[2])
            return ("split", f, t, left, right, float(self.samples[node]))

        return tree_arrays_from_nested(build(0, lo, hi), self.n_features, self.n_actions)

    def to_sklearn(self) -> DecisionTreeClassifier:
        """A fitted ``DecisionTreeClassifier`` that decides exactly as these arrays."""
        n = self.node_count
        nodes = np.zeros(n, dtype=_NODE_DTYPE)
        nodes["left_child"] = self.left
        nodes["right_child"] = self.right
        nodes["feature"] = self.feature
        nodes["threshold"] = self.threshold
        nodes["impurity"] = 0.0
        nodes["n_node_samples"] = np.maximum(np.round(self.samples), 1).astype(np.int64)
        nodes["weighted_n_node_samples"] = np.maximum(self.samples, 1e-12)
        nodes["missing_go_to_left"] = 0
        values = np.zeros((n, 1, self.n_actions), dtype=np.float64)
        values[np.arange(n), 0, self.action] = 1.0
        for node in range(n - 1, -1, -1):  # internal nodes: the mix of their children
            if not self.is_leaf[node]:
                lc, rc = self.left[node], self.right[node]
                wl, wr = nodes["weighted_n_node_samples"][[lc, rc]]
                values[node] = (wl * values[lc] + wr * values[rc]) / (wl + wr)
        tree = Tree(self.n_features, np.array([self.n_actions], dtype=np.intp), 1)
        tree.__setstate__({"max_depth": self.depth(), "node_count": n, "nodes": nodes,
                           "values": values})
        model = DecisionTreeClassifier()
        model.n_features_in_ = self.n_features
        model.n_outputs_ = 1
        model.classes_ = np.arange(self.n_actions)
        model.n_classes_ = self.n_actions
        model.max_features_ = self.n_features
        model.tree_ = tree
        return model


_NODE_DTYPE = np.dtype({
    "names": ["left_child", "right_child", "feature", "threshold", "impurity", "n_node_samples",
              "weighted_n_node_samples", "missing_go_to_left"],
    "formats": ["<i8", "<i8", "<i8", "<f8", "<f8", "<i8", "<f8", "u1"],
    "offsets": [0, 8, 16, 24, 32, 40, 48, 56], "itemsize": 64})


def tree_arrays_from_nested(root: tuple, n_features: int, n_actions: int) -> TreeArrays:
    """A TreeArrays from nested tuples ``("leaf", action, samples)`` and
    ``("split", feature, threshold, left, right, samples)``, nodes numbered in preorder."""
    feature: list[int] = []
    threshold: list[float] = []
    left: list[int] = []
    right: list[int] = []
    action: list[int] = []
    samples: list[float] = []

    def add(node: tuple) -> int:
        index = len(feature)
        feature.append(UNDEFINED)
        threshold.append(float(UNDEFINED))
        left.append(LEAF)
        right.append(LEAF)
        action.append(0)
        samples.append(0.0)
        if node[0] == "leaf":
            action[index] = node[1]
            samples[index] = node[2]
            return index
        _, f, t, l_node, r_node, weight = node
        feature[index], threshold[index], samples[index] = f, t, weight
        l_index = add(l_node)
        r_index = add(r_node)
        left[index], right[index] = l_index, r_index
        action[index] = action[l_index]
        return index

    add(root)
    return TreeArrays(np.array(feature, dtype=np.int64), np.array(threshold, dtype=np.float64),
                      np.array(left, dtype=np.int64), np.array(right, dtype=np.int64),
                      np.array(action, dtype=np.int64), np.array(samples, dtype=np.float64),
                      n_features, n_actions)
