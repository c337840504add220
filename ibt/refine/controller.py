"""Refinement by return of controller trees: thresholds, biases and weights tuned jointly.

A controller tree (:class:`ibt.distill.controller.ControllerArrays`) keeps its shape and which
features each test and command reads; CMA-ES (:func:`ibt.refine.by_return.cma_search`) moves
every threshold in units of its test's spread over the visited states, every command bias in
:data:`BIAS_SCALE` of its dimension's Box span, and every weight so that its term moves by the
same share of the span over the feature's spread. Generations are scored on fresh refinement
episodes, the stages' results compared on held-out selection episodes, as every refinement of
:mod:`ibt.refine.by_return` is. The result's constants are then rounded to the fewest
significant digits that keep its held-out return (:func:`round_constants`), so the BT prints
``main_engine := -1 + 10 * y - 10 * vy`` rather than seventeen digits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ibt.distill.controller import ControllerArrays, command_value, split_value, widen
from ibt.distill.oblique import ObliqueArrays
from ibt.refine.by_return import (
    RefineEpisodes,
    RefinementRecord,
    close_record,
    cma_search,
    held_out_means,
)
from ibt.tasks.settings import RefineConfig
from ibt.tasks.task import Task

BIAS_SCALE = 0.25  #: a bias's CMA-ES unit, as a share of its dimension's Box span
SPLIT_WEIGHT_SCALE = 0.25  #: a test weight's unit: moves its sum by this share of its spread
Tree = ControllerArrays | ObliqueArrays
DIGITS = (1, 2, 3, 4, 6, 17)  #: significant digits tried when rounding, fewest first


class ControllerPopulation:
    """Parameter sets of one controller or oblique tree decided in one batch (the ``Batch``
    protocol of :mod:`ibt.refine.by_return`): row ``i`` is decided by member ``members[i]``.
    An oblique tree (discrete actions) has no commands: ``bias`` and ``weights`` are None."""

    def __init__(self, tree: Tree, threshold: np.ndarray, split: np.ndarray,
                 bias: np.ndarray | None, weights: np.ndarray | None, low: np.ndarray | None,
                 high: np.ndarray | None) -> None:
        self.tree = tree
        n = len(tree.left)
        self.threshold = np.asarray(threshold, dtype=np.float64).reshape(-1, n)
        m = len(self.threshold)
        self.split = np.asarray(split, dtype=np.float64).reshape(m, n, -1)
        self.bias = None if bias is None else np.asarray(bias, np.float64).reshape(m, n, -1)
        self.weights = (None if weights is None else
                        np.asarray(weights, np.float64).reshape(m, n, *np.shape(weights)[-2:]))
        self.low, self.high = low, high

    @classmethod
    def of(cls, trees: list[Tree], task: Task) -> ControllerPopulation:
        """Trees of one shape as members."""
        threshold = np.stack([t.threshold for t in trees])
        split = np.stack([t.split for t in trees])
        controllers = [t for t in trees if isinstance(t, ControllerArrays)]
        if not controllers:
            return cls(trees[0], threshold, split, None, None, None, None)
        return cls(trees[0], threshold, split, np.stack([t.bias for t in controllers]),
                   np.stack([t.weights for t in controllers]), np.asarray(task.action_low),
                   np.asarray(task.action_high))

    def __len__(self) -> int:
        return len(self.threshold)

    def decide(self, features: np.ndarray, members: np.ndarray) -> np.ndarray:
        x = widen(features)
        t = self.tree
        node = np.zeros(len(x), dtype=np.int64)
        while True:
            inner = t.left[node] != -1
            if not inner.any():
                break
            rows = np.flatnonzero(inner)
            at = node[rows]
            who = members[rows]
            goes_left = split_value(self.split[who, at], x[rows]) <= self.threshold[who, at]
            node[rows] = np.where(goes_left, t.left[at], t.right[at])
        if self.bias is None or self.weights is None:
            return t.action[node]  # type: ignore[union-attr]
        out = command_value(self.bias[members, node], self.weights[members, node], x)
        return np.clip(out, self.low, self.high).astype(np.float32)


@dataclass
class ControllerRefinement(RefinementRecord[Any]):
    """A controller refinement's record: each stage's result and the chosen tree."""

    @staticmethod
    def candidate_from_doc(doc: dict[str, Any]) -> Tree:
        return tree_from_doc(doc)


def tree_from_doc(doc: dict[str, Any]) -> Tree:
    """A controller or oblique tree from its document (its ``learner`` names which)."""
    return (ObliqueArrays.from_doc(doc) if doc.get("learner") == "oblique"
            else ControllerArrays.from_doc(doc))


def _spreads(tree: Tree, task: Task, episodes: RefineEpisodes) -> tuple[np.ndarray, np.ndarray]:
    """Each feature's and each split's standard deviation over the states the tree visits (8
    fresh episodes), floored at a thousandth of the feature's box."""
    from ibt.evaluate.rollouts import visited_features

    population = ControllerPopulation.of([tree], task)
    x = widen(visited_features(task, lambda x: population.decide(x, np.zeros(len(x), np.int64)),
                               episodes.fresh(8), n_envs=8))
    box = np.asarray(task.high, dtype=np.float64) - np.asarray(task.low, dtype=np.float64)
    floor = np.where(np.isfinite(box) & (box > 0), 1e-3 * box, 1e-3)
    feature = np.maximum(x.std(axis=0), floor)
    split = np.array([max(float(np.std(x @ w)), 1e-3) for w in tree.split])
    return feature, split


def _cma_stage(tree: Tree, task: Task, config: RefineConfig, episodes: RefineEpisodes,
               rng: np.random.Generator) -> tuple[Tree, dict[str, Any]]:
    """CMA-ES on every threshold, the weights of every test of two or more features and, for
    a controller, every command's bias and weights (see the module docstring)."""
    feature_spread, split_spread = _spreads(tree, task, episodes)
    splits = np.flatnonzero(tree.left != -1)
    oblique = np.argwhere((tree.split != 0) & ((tree.split != 0).sum(axis=1) > 1)[:, None])
    parts = [split_spread[splits],
             SPLIT_WEIGHT_SCALE * split_spread[oblique[:, 0]] / feature_spread[oblique[:, 1]]]
    box = tree if isinstance(tree, ControllerArrays) else None
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    leaves = tree.leaves
    terms = np.zeros((0, 3), dtype=np.int64)
    if box is not None:
        span = high - low
        terms = np.argwhere(box.weights != 0)  # (node, dim, feature) of every command term
        parts += [np.tile(BIAS_SCALE * span, len(leaves)),
                  BIAS_SCALE * span[terms[:, 1]] / feature_spread[terms[:, 2]]]
    scale = np.concatenate(parts)
    k1 = len(splits)
    k2 = k1 + len(oblique)

    def members(z: np.ndarray) -> dict[str, np.ndarray]:
        z = np.atleast_2d(z) * scale
        m = len(z)
        t = np.repeat(tree.threshold[None], m, axis=0)
        t[:, splits] += z[:, :k1]
        w = np.repeat(tree.split[None], m, axis=0)
        w[:, oblique[:, 0], oblique[:, 1]] += z[:, k1:k2]
        out = {"threshold": t, "split": w}
        if box is not None:
            b = np.repeat(box.bias[None], m, axis=0)
            k3 = k2 + len(leaves) * box.n_dims
            b[:, leaves] += z[:, k2:k3].reshape(m, len(leaves), box.n_dims)
            c = np.repeat(box.weights[None], m, axis=0)
            c[:, terms[:, 0], terms[:, 1], terms[:, 2]] += z[:, k3:]
            out.update(bias=b, weights=c)
        return out

    def population(z: np.ndarray) -> ControllerPopulation:
        p = members(z)
        if box is None:
            return ControllerPopulation(tree, p["threshold"], p["split"], None, None, None, None)
        return ControllerPopulation(tree, p["threshold"], p["split"], p["bias"], p["weights"],
                                    low, high)

    if not len(scale):  # one leaf and nothing to tune (an oblique tree that always acts alike)
        return tree, {"generations": 0}
    best, info = cma_search(len(scale), config, episodes, rng, population)
    if best is None:
        return tree, info
    p = {k: v[0] for k, v in members(best).items()}
    return _with(tree, p), info


def _with(tree: Tree, p: dict[str, np.ndarray]) -> Tree:
    if isinstance(tree, ObliqueArrays):
        return tree.with_parameters(p["threshold"], p["split"])
    return tree.with_parameters(p["threshold"], p["bias"], p["weights"], p["split"])


def round_constants(tree: Tree, digits: int) -> Tree:
    """Every threshold, bias and weight rounded to ``digits`` significant digits (a weight
    that rounds to zero is dropped, so the rule reads one feature fewer)."""
    def rounded(a: np.ndarray) -> np.ndarray:
        out = np.array([float(f"{v:.{digits}g}") for v in a.ravel()]).reshape(a.shape)
        return out + 0.0

    if isinstance(tree, ObliqueArrays):
        return tree.with_parameters(rounded(tree.threshold), rounded(tree.split))
    return tree.with_parameters(rounded(tree.threshold), rounded(tree.bias),
                                rounded(tree.weights), rounded(tree.split))


def refine_controller(tree: Tree, task: Task, config: RefineConfig, seed: int = 0,
                      *, tolerance: float = 0.0, progress: bool = True
                      ) -> ControllerRefinement:
    """Refine ``tree`` on ``task``'s return (CMA-ES stages of ``config``), then round its
    constants to the fewest :data:`DIGITS` whose held-out mean is at most ``tolerance``
    (task units) below the unrounded tree's. The record's candidates are the source, each
    stage's result and the rounded winner; ``best_index`` the one kept."""
    if task.continuous != isinstance(tree, ControllerArrays):
        raise ValueError(f"{task.name} has {'a Box' if task.continuous else 'discrete'} "
                         "actions: refine a controller tree on a Box task, an oblique tree on "
                         "a discrete one")
    unknown = [s for s in config.stages if s != "cma"]
    if unknown:
        raise ValueError(f"a controller tree is refined by CMA-ES stages only, not {unknown}")
    rng = np.random.default_rng(seed)
    record = ControllerRefinement(task.name, seed, config.as_params(), candidates=[tree])
    episodes = RefineEpisodes.opened(task, seed, config, "refine controller", progress)
    current = tree
    for name in config.stages:
        current, info = _cma_stage(current, task, config, episodes, rng)
        record.candidates.append(current)
        record.stages.append({"stage": name, "episodes_used": episodes.used, **info})
    episodes.bar.close()

    def means(trees: list[Tree]) -> list[float]:
        return held_out_means(episodes, [ControllerPopulation.of([t], task) for t in trees],
                              config, seed)

    scores = means(record.candidates)
    best = max(range(len(scores)), key=lambda i: (scores[i], -i))
    for digits in DIGITS:
        candidate = round_constants(record.candidates[best], digits)
        score = means([candidate])[0]
        if score >= scores[best] - tolerance:
            record.candidates.append(candidate)
            record.stages.append({"stage": "round", "digits": digits})
            scores.append(score)
            break
    record.best_index = len(record.candidates) - 1 if record.stages[-1].get(
        "stage") == "round" else best
    return close_record(record, scores, episodes)
