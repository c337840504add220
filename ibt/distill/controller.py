"""Controller trees: small trees whose rules steer, learnt from an agent.

A *controller tree* is a binary tree whose splits test ``w1 * x[f1] + ... + wk * x[fk] <= t``
(k <= :data:`ibt.bt.linear.MAX_TERMS`; one term of weight 1 is an ordinary axis-aligned test)
and whose leaves, on a ``Box`` task, send a *linear command* per action dimension,
``b + v1 * x[g1] + ... + vk * x[gk]`` (at most ``MAX_TERMS`` features each), the shape of
Gymnasium's hand-written LunarLander controller (``main = 20 * hover_todo - 1``). It becomes a
BT of ``ScriptCondition`` tests and ``Script`` commands that stock BehaviorTree.CPP computes
exactly (:mod:`ibt.synth.controller`).

Everything is computed by the floating-point rule of :mod:`ibt.bt.linear`: features are float32
observations widened to double; a split's sum and a command's sum run in double over the
features in index order, left to right; arrays hold every weight densely, zeros where a term is
absent (adding ``0.0 * x`` leaves a double sum unchanged), so :meth:`ControllerArrays.decide`,
the population decisions of refinement and the BT agree bit for bit.

The learner (:class:`ModelTreeLearner`) plugs into the interactive loop of
:mod:`ibt.distill.loop`: each iteration fits a *model tree* on the aggregated labels, best
first, each split chosen where two least-squares fits of the agent's actions (one per side, on
every feature) leave the least squared error, then each leaf's commands refitted on at most
``max_terms`` features chosen by forward selection. Refinement by return then tunes
thresholds, biases and weights jointly (:mod:`ibt.refine.controller`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from ibt.bt.linear import MAX_TERMS
from ibt.distill.loop import (
    CommandVectors,
    Distillation,
    MethodSchedule,
    check_loop_settings,
    interactive_loop,
)
from ibt.experts.expert import Expert
from ibt.tasks.task import Task

LEARNER = "controller"  #: the learner's name in the registry and in cache keys
RIDGE = 1e-6  #: relative ridge of the split search's fits (keeps singular leaves solvable)
CUTS = 32  #: coarse thresholds per feature and leaf (quantiles), refined between neighbours
BLOCK_BYTES = 32 * 2**20  #: the split search's running sums are held a block of this size at a time


def widen(features: np.ndarray) -> np.ndarray:
    """Feature rows as the executors read them: float32 values widened to double."""
    return np.asarray(features, dtype=np.float32).astype(np.float64)


@dataclass(frozen=True)
class SplitTree:
    """The splits of a controller or oblique tree as arrays over ``n`` nodes (node 0 the root;
    ``left == -1``: a leaf): ``split`` ``(n, F)`` each split's weights (zeros at leaves),
    ``threshold`` ``(n,)``. What the leaves hold is the subclass's."""

    left: np.ndarray
    right: np.ndarray
    split: np.ndarray
    threshold: np.ndarray

    @property
    def leaves(self) -> np.ndarray:
        return np.flatnonzero(self.left == -1)

    @property
    def n_leaves(self) -> int:
        return int((self.left == -1).sum())

    @property
    def node_count(self) -> int:
        return len(self.left)

    @property
    def tree_(self) -> SplitTree:
        """Itself: the interactive loop reads a tree's size by scikit-learn's names."""
        return self

    def get_n_leaves(self) -> int:
        return self.n_leaves

    def leaf_of(self, x: np.ndarray) -> np.ndarray:
        """The leaf each widened feature row reaches."""
        node = np.zeros(len(x), dtype=np.int64)
        while True:
            inner = self.left[node] != -1
            if not inner.any():
                return node
            rows = np.flatnonzero(inner)
            at = node[rows]
            goes_left = split_value(self.split[at], x[rows]) <= self.threshold[at]
            node[rows] = np.where(goes_left, self.left[at], self.right[at])

    def to_doc(self) -> dict[str, Any]:
        raise NotImplementedError

    def digest(self) -> str:
        """The tree's identity (its document's SHA-256, 16 hex digits)."""
        import json

        return hashlib.sha256(json.dumps(self.to_doc(), sort_keys=True).encode()
                              ).hexdigest()[:16]

    def _size(self, command_terms: int) -> dict[str, int]:
        inner = self.left != -1
        return {"rules": self.n_leaves, "tests": int(inner.sum()),
                "test_terms": int((self.split[inner] != 0).sum()),
                "command_terms": command_terms}


@dataclass(frozen=True)
class ControllerArrays(SplitTree):
    """A controller tree: :class:`SplitTree`'s splits, and ``bias`` ``(n, D)`` and ``weights``
    ``(n, D, F)``: each leaf's commands (zeros at splits)."""

    bias: np.ndarray
    weights: np.ndarray

    @property
    def n_features(self) -> int:
        return int(self.split.shape[1])

    @property
    def n_dims(self) -> int:
        return int(self.bias.shape[1])

    def decide(self, features: np.ndarray) -> np.ndarray:
        """The command vectors ``(n, D)`` in double on feature rows (not clipped)."""
        x = widen(features)
        leaf = self.leaf_of(x)
        return command_value(self.bias[leaf], self.weights[leaf], x)

    def with_parameters(self, threshold: np.ndarray, bias: np.ndarray, weights: np.ndarray,
                        split: np.ndarray | None = None) -> ControllerArrays:
        return ControllerArrays(self.left, self.right,
                                self.split if split is None else np.asarray(split, np.float64),
                                np.asarray(threshold, np.float64), np.asarray(bias, np.float64),
                                np.asarray(weights, np.float64))

    def to_doc(self) -> dict[str, Any]:
        """Plain JSON data (floats by ``repr``: exact round trips)."""
        return {"learner": LEARNER, "left": self.left.tolist(), "right": self.right.tolist(),
                "split": self.split.tolist(), "threshold": self.threshold.tolist(),
                "bias": self.bias.tolist(), "weights": self.weights.tolist()}

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> ControllerArrays:
        n = len(doc["left"])
        split = np.asarray(doc["split"], dtype=np.float64).reshape(n, -1)
        bias = np.asarray(doc["bias"], dtype=np.float64).reshape(n, -1)
        return cls(np.asarray(doc["left"], dtype=np.int64), np.asarray(doc["right"], np.int64),
                   split, np.asarray(doc["threshold"], dtype=np.float64), bias,
                   np.asarray(doc["weights"], dtype=np.float64).reshape(
                       n, bias.shape[1], split.shape[1]))

    def size(self) -> dict[str, int]:
        """Rules (leaves), tests, and terms in tests and commands (how readable it is)."""
        return self._size(int((self.weights[self.left == -1] != 0).sum()))


def split_value(weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Row ``r``'s split sum ``weights[r] . x[r]``, in double over features in index order."""
    total = np.zeros(len(x))
    for f in range(x.shape[1]):
        total = total + weights[:, f] * x[:, f]
    return total


def command_value(bias: np.ndarray, weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Row ``r``'s commands ``bias[r] + weights[r] @ x[r]``, summed left to right in double
    (``bias`` ``(n, D)``, ``weights`` ``(n, D, F)``)."""
    total = np.array(bias, dtype=np.float64, copy=True)
    for f in range(x.shape[1]):
        total = total + weights[:, :, f] * x[:, f, None]
    return total


# ----------------------------------------------------------------------------- fitting
def _design(x: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones(len(x)), x])


def _sse(a: np.ndarray, b: np.ndarray, yy: np.ndarray) -> np.ndarray:
    """Residual sum of squares of ridge fits from stacked normal equations: ``a`` ``(k, p,
    p)``, ``b`` ``(k, p, D)``, ``yy`` ``(k,)``."""
    p = a.shape[-1]
    scale = np.maximum(np.trace(a, axis1=1, axis2=2) / p, 1e-12)
    ridge = a + (RIDGE * scale)[:, None, None] * np.eye(p)
    beta = np.linalg.solve(ridge, b)
    return yy - np.einsum("kpd,kpd->k", beta, b)


class _RunningSums:
    """The split search's running sums over rows sorted by one feature: of ``z z^T``, ``z y^T``
    and ``y . y`` (``z`` a row of the design, ``y`` its actions), read at chosen rows.

    They are accumulated a block of :data:`BLOCK_BYTES` at a time, each block's running sum
    started from the last one's total: the same sequential sums, bit for bit, as one running
    sum over every row, in memory bounded by the block instead of ``rows x features^2`` (a
    40,000-state, 100-feature search would otherwise hold 3 GB)."""

    def __init__(self, zs: np.ndarray, ys: np.ndarray) -> None:
        self.zs, self.ys = zs, ys
        p, d = zs.shape[1], ys.shape[1]
        self.block = max(1, BLOCK_BYTES // (8 * p * (p + d) + 8))

    def at(self, rows: np.ndarray, start: int = 0,
           carry: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The sums over rows ``0..r`` for each ``r`` of ``rows`` (ascending, from ``start -
        1``), ``carry`` holding the sums over the rows before ``start``."""
        zs, ys = self.zs, self.ys
        p, d = zs.shape[1], ys.shape[1]
        outer, cross, squares = carry if carry is not None else (
            np.zeros((p, p)), np.zeros((p, d)), np.zeros(()))
        found = (np.empty((len(rows), p, p)), np.empty((len(rows), p, d)), np.empty(len(rows)))
        for into, sums in zip(found, (outer, cross, squares), strict=True):
            into[rows == start - 1] = sums
        stop = int(rows[-1]) + 1 if len(rows) else start
        size = min(self.block, max(0, stop - start))
        buffers = (np.empty((size + 1, p, p)), np.empty((size + 1, p, d)), np.empty(size + 1))
        for first in range(start, stop, self.block):
            last = min(first + self.block, stop)
            z, y = zs[first:last], ys[first:last]
            m = last - first
            block = tuple(b[:m + 1] for b in buffers)
            # the carry as the first term: the running sum goes on as one sequential sum
            block[0][0], block[1][0], block[2][0] = outer, cross, squares
            np.multiply(z[:, :, None], z[:, None, :], out=block[0][1:])
            np.multiply(z[:, :, None], y[:, None, :], out=block[1][1:])
            np.sum(y * y, axis=1, out=block[2][1:])
            for sums in block:
                np.cumsum(sums, axis=0, out=sums)
            here = (rows >= first) & (rows < last)
            for into, sums in zip(found, block, strict=True):
                into[here] = sums[rows[here] - first + 1]
            outer, cross, squares = (sums[-1].copy() for sums in block)
        return found


def _best_cut(xs: np.ndarray, zs: np.ndarray, ys: np.ndarray, total: float, min_leaf: int
              ) -> tuple[float, float] | None:
    """``(gain, threshold)`` of the best cut of rows sorted by one feature (values ``xs``):
    :data:`CUTS` quantile cuts first, then every position between the best one's neighbours."""
    n = len(xs)
    sums = _RunningSums(zs, ys)

    def valid(cuts: np.ndarray) -> np.ndarray:
        cuts = np.unique(cuts[(cuts >= min_leaf) & (cuts <= n - min_leaf)])
        return cuts[xs[cuts - 1] < xs[np.minimum(cuts, n - 1)]]  # between two values

    coarse = valid(np.quantile(np.arange(min_leaf, n - min_leaf + 1),
                               np.linspace(0, 1, CUTS)).astype(np.int64))
    if not len(coarse):
        return None
    read = np.unique(np.concatenate([coarse - 1, [min_leaf - 1, n - 1]]))
    known = dict(zip(read.tolist(), zip(*sums.at(read), strict=True), strict=True))
    whole = known[n - 1]

    def gains(a: np.ndarray, b: np.ndarray, yy: np.ndarray) -> np.ndarray:
        return total - _sse(a, b, yy) - _sse(whole[0] - a, whole[1] - b, whole[2] - yy)

    k = int(np.argmax(gains(*(np.stack([known[int(c) - 1][i] for c in coarse])
                               for i in range(3)))))
    lo = coarse[k - 1] if k > 0 else min_leaf
    hi = coarse[k + 1] if k + 1 < len(coarse) else n - min_leaf
    fine = valid(np.arange(lo, hi + 1))
    parts, start, carry = [], int(lo), known[int(lo) - 1]
    for part in np.array_split(fine, -(-len(fine) // sums.block)):  # a block at a time
        found = sums.at(part - 1, start, carry)
        parts.append(gains(*found))
        start, carry = int(part[-1]), tuple(f[-1] for f in found)
    fine_gains = np.concatenate(parts)
    k = int(np.argmax(fine_gains))
    cut = fine[k]
    threshold = float((xs[cut - 1] + xs[cut]) / 2)
    if not xs[cut - 1] <= threshold < xs[cut]:
        threshold = float(xs[cut - 1])
    return float(fine_gains[k]), threshold


def _best_split(x: np.ndarray, y: np.ndarray, min_leaf: int
                ) -> tuple[float, int, float] | None:
    """``(gain, feature, threshold)`` of the axis split whose two least-squares fits leave the
    least error, or None when no split leaves ``min_leaf`` states on both sides."""
    n = len(x)
    if n < 2 * min_leaf:
        return None
    z = _design(x)
    total = _sse((z.T @ z)[None], (z.T @ y)[None], np.array([(y * y).sum()]))[0]
    best: tuple[float, int, float] | None = None
    for f in range(x.shape[1]):
        order = np.argsort(x[:, f], kind="stable")
        found = _best_cut(x[order, f], z[order], y[order], total, min_leaf)
        if found is not None and (best is None or found[0] > best[0]):
            best = (found[0], f, found[1])
    return best


def sparse_fit(x: np.ndarray, y: np.ndarray, max_terms: int) -> tuple[float, np.ndarray]:
    """``(bias, weights)`` of a least-squares fit of one action dimension on at most
    ``max_terms`` features, chosen by forward selection (each step the feature that lowers the
    error most; a step that lowers it by less than 0.1 % of the variance stops)."""
    chosen: list[int] = []
    weights = np.zeros(x.shape[1])
    bias = float(y.mean()) if len(y) else 0.0
    error = float(((y - bias) ** 2).sum())
    floor = 1e-3 * error
    while len(chosen) < max_terms:
        trial = None
        for f in range(x.shape[1]):
            if f in chosen:
                continue
            z = _design(x[:, [*chosen, f]])
            beta, *_ = np.linalg.lstsq(z, y, rcond=None)
            e = float(((z @ beta - y) ** 2).sum())
            if trial is None or e < trial[0]:
                trial = (e, f, beta)
        if trial is None or error - trial[0] <= floor:
            break
        error, f, beta = trial
        chosen.append(f)
        bias = float(beta[0])
        weights[:] = 0.0
        weights[chosen] = beta[1:]
    return bias, weights


def grow_best_first(n_rows: int, max_leaves: int,
                    propose: Callable[[np.ndarray], tuple[float, Any, float] | None],
                    goes_left: Callable[[np.ndarray, Any, float], np.ndarray]
                    ) -> list[dict[str, Any]]:
    """The nodes of a tree grown best first to at most ``max_leaves`` leaves: every leaf's
    best split is proposed once (``propose(rows)``: ``(gain, split, threshold)`` or None), the
    leaf of the largest gain is split (ties: the leaf made first), ``goes_left(rows, split,
    threshold)`` sends its rows. Each node holds its ``rows``; a split node also its
    ``split``, ``threshold`` and the indices of its ``left`` and ``right`` children."""
    nodes: list[dict[str, Any]] = [{"rows": np.arange(n_rows)}]
    frontier = [0]
    proposals: dict[int, tuple[float, Any, float] | None] = {}
    while len(frontier) < max_leaves:
        for node in frontier:
            if node not in proposals:
                proposals[node] = propose(nodes[node]["rows"])
        ready = [(found[0], n) for n in frontier if (found := proposals[n]) is not None]
        if not ready:
            break
        _, node = max(ready, key=lambda item: (item[0], -item[1]))
        chosen = proposals[node]
        assert chosen is not None
        _, split, threshold = chosen
        rows = nodes[node]["rows"]
        left = goes_left(rows, split, threshold)
        nodes[node].update(split=split, threshold=threshold,
                           left=len(nodes), right=len(nodes) + 1)
        nodes.append({"rows": rows[left]})
        nodes.append({"rows": rows[~left]})
        frontier.remove(node)
        frontier += [len(nodes) - 2, len(nodes) - 1]
    return nodes


def fit_model_tree(x: np.ndarray, y: np.ndarray, max_leaves: int, *, max_terms: int = MAX_TERMS,
                   min_leaf: int | None = None) -> ControllerArrays:
    """A model tree of at most ``max_leaves`` leaves on widened features ``x`` and action
    vectors ``y`` ``(n, D)``: best-first splits (see the module docstring)."""
    x, y = widen(x), np.asarray(y, dtype=np.float64).reshape(len(x), -1)
    min_leaf = min_leaf or max(20, len(x) // (8 * max_leaves))
    nodes = grow_best_first(len(x), max_leaves,
                            lambda rows: _best_split(x[rows], y[rows], min_leaf),
                            lambda rows, feature, threshold: x[rows, feature] <= threshold)
    n, n_features, n_dims = len(nodes), x.shape[1], y.shape[1]
    arrays = ControllerArrays(np.full(n, -1, np.int64), np.full(n, -1, np.int64),
                              np.zeros((n, n_features)), np.zeros(n), np.zeros((n, n_dims)),
                              np.zeros((n, n_dims, n_features)))
    for k, entry in enumerate(nodes):
        if "split" in entry:  # a feature's index
            arrays.left[k], arrays.right[k] = entry["left"], entry["right"]
            arrays.split[k, entry["split"]] = 1.0
            arrays.threshold[k] = entry["threshold"]
            continue
        rows = entry["rows"]
        for d in range(n_dims):
            arrays.bias[k, d], arrays.weights[k, d] = sparse_fit(x[rows], y[rows, d], max_terms)
    return arrays


# ------------------------------------------------------------------------ the interactive loop
@dataclass(frozen=True)
class ControllerConfig(MethodSchedule):
    """Everything that determines a controller distillation (with the agent and seed); the
    oblique learner's settings are the same with tests of at least one feature
    (:class:`ibt.distill.oblique.ObliqueConfig`)."""

    learner: ClassVar[str] = LEARNER  # named in the cache key
    min_terms: ClassVar[int] = 0  # a leaf's command may be a constant
    method: str = "dagger"
    n_iterations: int = 10
    labels_per_iteration: int = 4000
    selection_episodes: int = 20
    max_leaves: int = 4
    max_terms: int = MAX_TERMS
    collect_envs: int = 2
    eval_envs: int = 20

    def __post_init__(self) -> None:
        check_loop_settings(self.method, self.n_iterations, self.labels_per_iteration)
        if self.max_leaves < 1:
            raise ValueError(f"max_leaves must be at least 1, got {self.max_leaves}")
        if not self.min_terms <= self.max_terms <= MAX_TERMS:
            raise ValueError(f"max_terms must be {self.min_terms} to {MAX_TERMS}, got "
                             f"{self.max_terms}")

    def as_params(self) -> dict[str, Any]:
        return {"learner": self.learner, **asdict(self)}


@dataclass(frozen=True)
class ModelTreeLearner(CommandVectors):
    """The interactive loop's learner for controller trees on a ``Box`` task."""

    config: ControllerConfig
    task: Task

    def fit(self, x: np.ndarray, y: np.ndarray) -> ControllerArrays:
        low, high = np.asarray(self.task.action_low), np.asarray(self.task.action_high)
        target = np.clip(np.asarray(y, dtype=np.float64).reshape(len(x), -1), low, high)
        return fit_model_tree(x, target, self.config.max_leaves, max_terms=self.config.max_terms)

    def signature(self, tree: ControllerArrays) -> bytes:
        return tree.digest().encode()

    def predictor(self, tree: ControllerArrays) -> Callable[[np.ndarray], np.ndarray]:
        low, high = np.asarray(self.task.action_low), np.asarray(self.task.action_high)
        return lambda features: np.clip(tree.decide(features), low, high).astype(np.float32)


def distill_controller(task: Task, expert: Expert, config: ControllerConfig, seed: int = 0, *,
                       progress: bool = True) -> Distillation:
    """The interactive loop with a :class:`ModelTreeLearner` on a ``Box`` task; the record's
    ``best_tree`` is a :class:`ControllerArrays`."""
    if not task.continuous:
        raise ValueError(f"{task.name} has discrete actions; controller trees send linear "
                         "commands to a Box action space")
    return interactive_loop(task, expert, config, seed, ModelTreeLearner(config, task),
                            progress=progress)
