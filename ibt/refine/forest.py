"""Trees of different shapes decided side by side in one batch (the structure search's rollouts).

The structure search by return (:mod:`ibt.refine.structure`) scores parents and children of
different shapes on the same episodes; stepping them as one batch of environments needs one
policy that routes every row through its own tree. :class:`Forest` is that policy: the trees
laid out as flat arrays, walked all at once, reading only the columns some split tests.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ibt.distill.relational import AugmentedTask
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.task import Task

#: batches up to this many rows are decided row by row (see :meth:`Forest._decide_rows`)
SMALL_BATCH = 16


class Forest:
    """Trees of different shapes decided side by side: ``decide(x, members)`` routes row ``i``
    through tree ``members[i]`` (float32 features widened to float64, as scikit-learn).

    A rollout reads only the columns some split tests (:meth:`reader`: on a relational search's
    hundred-odd candidate columns, computing them all on every step cost more than the trees),
    and walks all trees at once on flat arrays; a leaf points to itself, so rows that reach a
    leaf early stay there."""

    def __init__(self, trees: list[TreeArrays]) -> None:
        self.trees = trees
        width = max(t.node_count for t in trees)
        self.width = width
        tested = sorted({int(f) for t in trees for f in t.feature[~t.is_leaf]})
        self.columns = np.array(tested or [0], dtype=np.int64)  # the features some split reads
        position = {c: k for k, c in enumerate(self.columns.tolist())}
        size = len(trees) * width
        self.feature = np.zeros(size, dtype=np.int64)  # position in ``columns``
        self.threshold = np.zeros(size, dtype=np.float64)
        self.left = np.arange(size, dtype=np.int64)  # flat node numbers; a leaf: itself
        self.right = np.arange(size, dtype=np.int64)
        self.action = np.zeros(size, dtype=np.int64)
        for i, t in enumerate(trees):
            base, split = i * width, ~t.is_leaf
            nodes = base + np.flatnonzero(split)
            self.feature[nodes] = [position[int(f)] for f in t.feature[split]]
            self.threshold[nodes] = t.threshold[split]
            self.left[nodes] = base + t.left[split]
            self.right[nodes] = base + t.right[split]
            self.action[base:base + t.node_count] = t.action
        self.depth = max(t.depth() for t in trees)
        self._lists: tuple[list, ...] | None = None

    def __len__(self) -> int:
        return len(self.trees)

    def decide(self, features: np.ndarray, members: np.ndarray) -> np.ndarray:
        x = np.asarray(features, dtype=np.float32).astype(np.float64)
        return self.decide_columns(x[:, self.columns], members)

    def decide_columns(self, x: np.ndarray, members: np.ndarray) -> np.ndarray:
        """:meth:`decide` on rows of :attr:`columns` only, already widened to float64
        (:meth:`reader`'s rows)."""
        if len(x) <= SMALL_BATCH:
            return self._decide_rows(x, members)
        n, n_columns = x.shape
        flat = x.ravel()
        row_start = np.arange(n, dtype=np.int64) * n_columns
        node = np.asarray(members, dtype=np.int64) * self.width
        for _ in range(self.depth):
            go_left = flat[row_start + self.feature[node]] <= self.threshold[node]
            node = np.where(go_left, self.left[node], self.right[node])
        return self.action[node]

    def _decide_rows(self, x: np.ndarray, members: np.ndarray) -> np.ndarray:
        """A rollout's last few rows: walking in Python beats array passes (the same float64
        comparisons)."""
        if self._lists is None:
            self._lists = (self.feature.tolist(), self.threshold.tolist(), self.left.tolist(),
                           self.right.tolist(), self.action.tolist())
        feature, threshold, left, right, action = self._lists
        width = self.width
        out = []
        for row, member in zip(x.tolist(), np.asarray(members).tolist(), strict=True):
            node = member * width
            while left[node] != node:
                node = left[node] if row[feature[node]] <= threshold[node] else right[node]
            out.append(action[node])
        return np.array(out, dtype=np.int64)

    def reader(self, task: Task) -> Callable[[np.ndarray], np.ndarray]:
        """Raw observations -> the :attr:`columns` of ``task.features``, widened as
        :meth:`decide` widens them; a relational search's derived columns are computed by
        :meth:`ibt.bt.linear.FeatureMap.augment`'s rule (double products and sum, then the
        float32 value) for the tested ones only."""
        columns = self.columns
        fmap = getattr(task, "feature_map", None)
        if not isinstance(task, AugmentedTask) or fmap is None:
            def read(obs: np.ndarray) -> np.ndarray:
                return task.features(obs).astype(np.float64)[:, columns]
            return read
        n = fmap.n_features
        observed = np.flatnonzero(columns < n)
        derived = np.flatnonzero(columns >= n)
        forms = [fmap.form(int(c)) for c in columns[derived]]
        first = np.array([f.i for f in forms], dtype=np.int64)
        second = np.array([f.j for f in forms], dtype=np.int64)
        w1 = np.array([f.w1 for f in forms], dtype=np.float64)
        w2 = np.array([f.w2 for f in forms], dtype=np.float64)
        observed_columns = columns[observed]

        def read_augmented(obs: np.ndarray) -> np.ndarray:
            x = Task.features(task, obs).astype(np.float64)
            out = np.empty((len(x), len(columns)), dtype=np.float64)
            out[:, observed] = x[:, observed_columns]
            if len(forms):
                values = w1 * x[:, first] + w2 * x[:, second]
                with np.errstate(over="ignore"):
                    out[:, derived] = values.astype(np.float32)
            return out
        return read_augmented


__all__ = ["SMALL_BATCH", "Forest"]
