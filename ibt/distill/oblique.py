"""Oblique trees for discrete actions: tests ``w1 * x[f1] + ... + wk * x[fk] <= t`` (k <= 4).

The discrete twin of the controller trees (:mod:`ibt.distill.controller`): the same splits and
the same floating-point rule, leaves that name an action. Gymnasium's hand-written LunarLander
controller decides by such tests (``hover_todo > |angle_todo|`` compares sums of three and four
features); an axis-aligned tree needs many leaves to approximate one of them.

The learner (:class:`ObliqueLearner`) plugs into the interactive loop of
:mod:`ibt.distill.loop` (labels, Q-gap weights and resampling as every discrete learner). Each
leaf is split best-first where the weighted Gini impurity falls most, among the axis-aligned
splits and, per action, a one-against-the-rest logistic regression on at most ``max_terms``
features (the strongest of a first fit on every feature, refitted, weights scaled so the
largest is 1), whose projection is cut at its best threshold. Refinement by return then tunes
every threshold and weight (:mod:`ibt.refine.controller`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ibt.bt.linear import MAX_TERMS
from ibt.distill.controller import (
    ControllerConfig,
    SplitTree,
    grow_best_first,
    split_value,
    widen,
)
from ibt.distill.loop import Distillation, interactive_loop, mix
from ibt.experts.expert import Expert
from ibt.tasks.task import Task

LEARNER = "oblique"
MIN_SHARE = 0.02  #: an action with a smaller share of a leaf's labels gets no oblique proposal
RELEVANT = 0.05  #: features weighing less than this share of the largest are left out


@dataclass(frozen=True)
class ObliqueArrays(SplitTree):
    """An oblique tree: :class:`ibt.distill.controller.SplitTree`'s splits, and ``action``
    ``(n,)`` each leaf's action (-1 at splits)."""

    action: np.ndarray

    def decide(self, features: np.ndarray) -> np.ndarray:
        return self.action[self.leaf_of(widen(features))]

    def with_parameters(self, threshold: np.ndarray, split: np.ndarray) -> ObliqueArrays:
        return ObliqueArrays(self.left, self.right, np.asarray(split, np.float64),
                             np.asarray(threshold, np.float64), self.action)

    def to_doc(self) -> dict[str, Any]:
        return {"learner": LEARNER, "left": self.left.tolist(), "right": self.right.tolist(),
                "split": self.split.tolist(), "threshold": self.threshold.tolist(),
                "action": self.action.tolist()}

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> ObliqueArrays:
        n = len(doc["left"])
        return cls(np.asarray(doc["left"], np.int64), np.asarray(doc["right"], np.int64),
                   np.asarray(doc["split"], np.float64).reshape(n, -1),
                   np.asarray(doc["threshold"], np.float64), np.asarray(doc["action"], np.int64))

    def size(self) -> dict[str, int]:
        return self._size(0)


def _gini_cut(z: np.ndarray, y: np.ndarray, n_classes: int, min_leaf: int
              ) -> tuple[float, float] | None:
    """``(impurity decrease, threshold)`` of the best cut of values ``z`` for labels ``y``
    (counts weighted equally: the loop has resampled by weight already)."""
    n = len(z)
    if n < 2 * min_leaf:
        return None
    order = np.argsort(z, kind="stable")
    zs, ys = z[order], y[order]
    onehot = np.zeros((n, n_classes))
    onehot[np.arange(n), ys] = 1.0
    left = np.cumsum(onehot, axis=0)[:-1]
    right = left[-1] + onehot[-1] - left
    k = np.arange(1, n)
    gini_left = k - (left ** 2).sum(axis=1) / k
    gini_right = (n - k) - (right ** 2).sum(axis=1) / (n - k)
    total = n - (onehot.sum(axis=0) ** 2).sum() / n
    ok = (zs[:-1] < zs[1:]) & (k >= min_leaf) & (n - k >= min_leaf)
    if not ok.any():
        return None
    gain = np.where(ok, total - gini_left - gini_right, -np.inf)
    cut = int(np.argmax(gain))
    threshold = float((zs[cut] + zs[cut + 1]) / 2)
    if not zs[cut] <= threshold < zs[cut + 1]:
        threshold = float(zs[cut])
    return float(gain[cut]), threshold


def _oblique_directions(x: np.ndarray, y: np.ndarray, n_classes: int, max_terms: int
                        ) -> list[np.ndarray]:
    """Per frequent action, a one-against-the-rest direction on at most ``max_terms``
    features (the largest weight 1, three significant digits)."""
    from sklearn.linear_model import LogisticRegression

    scale = x.std(axis=0)
    scale[scale == 0] = 1.0
    xs = (x - x.mean(axis=0)) / scale
    out = []
    shares = np.bincount(y, minlength=n_classes) / len(y)
    for action in np.flatnonzero((shares >= MIN_SHARE) & (shares <= 1 - MIN_SHARE)):
        target = (y == action).astype(int)
        first = LogisticRegression(C=1.0, max_iter=200).fit(xs, target)
        strength = np.abs(first.coef_[0])  # on standardised features: comparable
        chosen = [f for f in np.argsort(-strength)[:max_terms]
                  if strength[f] >= RELEVANT * strength.max()]
        model = LogisticRegression(C=1.0, max_iter=200).fit(xs[:, chosen], target)
        weights = np.zeros(x.shape[1])
        weights[chosen] = model.coef_[0] / scale[chosen]  # in the features' own units
        if not np.any(weights):
            continue
        weights /= np.abs(weights).max()
        out.append(np.array([float(f"{w:.3g}") for w in weights]))
    return out


def fit_oblique_tree(x: np.ndarray, y: np.ndarray, n_classes: int, max_leaves: int, *,
                     max_terms: int = MAX_TERMS, min_leaf: int | None = None) -> ObliqueArrays:
    """An oblique tree of at most ``max_leaves`` leaves (see the module docstring)."""
    x, y = widen(x), np.asarray(y, dtype=np.int64)
    min_leaf = min_leaf or max(10, len(x) // (20 * max_leaves))

    def propose(rows: np.ndarray) -> tuple[float, np.ndarray, float] | None:
        best: tuple[float, np.ndarray, float] | None = None
        directions = [np.eye(x.shape[1])[f] for f in range(x.shape[1])]
        if len(np.unique(y[rows])) > 1 and max_terms > 1:
            directions += _oblique_directions(x[rows], y[rows], n_classes, max_terms)
        for w in directions:
            found = _gini_cut(split_value(np.broadcast_to(w, (len(rows), len(w))), x[rows]),
                              y[rows], n_classes, min_leaf)
            if found is not None and (best is None or found[0] > best[0] + 1e-9):
                best = (found[0], w, found[1])
        return best if best is not None and best[0] > 0 else None

    def goes_left(rows: np.ndarray, w: np.ndarray, threshold: float) -> np.ndarray:
        return split_value(np.broadcast_to(w, (len(rows), len(w))), x[rows]) <= threshold

    nodes = grow_best_first(len(x), max_leaves, propose, goes_left)
    n = len(nodes)
    tree = ObliqueArrays(np.full(n, -1, np.int64), np.full(n, -1, np.int64),
                         np.zeros((n, x.shape[1])), np.zeros(n), np.full(n, -1, np.int64))
    for k, entry in enumerate(nodes):
        if "split" in entry:
            tree.left[k], tree.right[k] = entry["left"], entry["right"]
            tree.split[k] = entry["split"]
            tree.threshold[k] = entry["threshold"]
        else:
            counts = np.bincount(y[entry["rows"]], minlength=n_classes)
            tree.action[k] = int(np.argmax(counts))
    return tree


@dataclass(frozen=True)
class ObliqueConfig(ControllerConfig):
    """Everything that determines an oblique distillation (with the agent and seed): the
    controller's settings, its tests of at least one feature."""

    learner: ClassVar[str] = LEARNER
    min_terms: ClassVar[int] = 1


@dataclass(frozen=True)
class ObliqueLearner:
    """The interactive loop's learner for oblique trees on a discrete task."""

    config: ObliqueConfig
    n_actions: int

    def label(self, expert: Expert, obs: np.ndarray, weighted: bool
              ) -> tuple[np.ndarray, np.ndarray]:
        return expert.label(obs)

    def fit(self, x: np.ndarray, y: np.ndarray) -> ObliqueArrays:
        return fit_oblique_tree(x, y, self.n_actions, self.config.max_leaves,
                                max_terms=self.config.max_terms)

    def signature(self, tree: ObliqueArrays) -> bytes:
        return tree.digest().encode()

    def predictor(self, tree: ObliqueArrays) -> Callable[[np.ndarray], np.ndarray]:
        return tree.decide

    def mix(self, expert_actions: np.ndarray, tree_actions: np.ndarray, beta: float,
            rng: np.random.Generator) -> np.ndarray:
        return mix(expert_actions, tree_actions, beta, rng)


def distill_oblique(task: Task, expert: Expert, config: ObliqueConfig, seed: int = 0, *,
                    progress: bool = True) -> Distillation:
    """The interactive loop with an :class:`ObliqueLearner`; ``best_tree`` is an
    :class:`ObliqueArrays`."""
    if task.continuous:
        raise ValueError(f"{task.name} has a Box action space; use the controller learner")
    return interactive_loop(task, expert, config, seed, ObliqueLearner(config, task.n_actions),
                            progress=progress)
