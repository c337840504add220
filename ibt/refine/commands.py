"""Refinement by return of command trees: Imitation-BT+ for continuous actions.

A command tree (:class:`ibt.synth.commands.CommandTree`) is an axis-aligned tree whose leaves
name one of ``k`` commands, each a vector inside the task's Box. Its return is raised by
CMA-ES (the ``cma`` package, as in :mod:`ibt.refine.by_return`) on the thresholds and the
command values *jointly*: each threshold moves in units of the spread of its feature over the
states the tree visits, each command value in units of a quarter of its dimension's Box span,
and a value is clipped to the Box. The tree's shape and the leaves' command ids never change,
so the BT synthesised from a refined tree has the same readable set of named commands.

The seed discipline, the budget in episodes and the held-out choice are those of
:mod:`ibt.refine.by_return`, reused rather than copied: refinement episodes come from its
``RefineEpisodes`` (seeds from :data:`ibt.evaluate.rollouts.REFINE_SEED_BASE`, disjoint from the
distillation's training and selection episodes and from the final evaluation; every member of a
generation on the same fresh episodes, each generation on new ones); the stages' results, the
source included, are compared on held-out selection episodes
(:data:`ibt.evaluate.rollouts.REFINE_SELECTION_OFFSET`) and the best is kept. Command values are
rounded (to :data:`ibt.synth.commands.DECIMALS` decimals) before any comparison, so the tree chosen
is exactly the one the BT writes. Deterministic given the seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ibt.refine.by_return import (
    RefineEpisodes,
    RefinementRecord,
    ThresholdSets,
    close_record,
    cma_search,
    held_out_means,
    visited_spread,
)
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.settings import RefineConfig
from ibt.tasks.task import Task

VALUE_SCALE = 0.25  #: a command value's CMA-ES unit, as a share of its dimension's Box span


@dataclass(frozen=True)
class CommandArrays:
    """A command tree as arrays: ``structure.action`` is each leaf's command id, ``values`` the
    command table ``(k, dims)``."""

    structure: TreeArrays
    values: np.ndarray

    @classmethod
    def from_command_tree(cls, tree: Any) -> CommandArrays:
        """The arrays of a :class:`ibt.synth.commands.CommandTree` (its classifier's leaves
        hold command ids; the conversion back is :func:`ibt.engine.synthesis.command_tree_of`)."""
        return cls(TreeArrays.from_sklearn(tree.tree), tree.commands.array().astype(np.float64))

    def with_parameters(self, threshold: np.ndarray, values: np.ndarray) -> CommandArrays:
        return CommandArrays(self.structure.with_parameters(threshold=threshold),
                             np.asarray(values, dtype=np.float64))

    def simplified(self) -> CommandArrays:
        """Dead splits removed (thresholds moved outside their ancestors' interval)."""
        return CommandArrays(self.structure.simplified(), self.values)

    def actions(self, features: np.ndarray) -> np.ndarray:
        """The command vectors ``(n, dims)`` on feature rows."""
        return self.values[self.structure.predict(features)].astype(np.float32)

    @property
    def n_leaves(self) -> int:
        return self.structure.n_leaves

    @property
    def n_commands(self) -> int:
        return len(self.values)

    def to_doc(self) -> dict[str, Any]:
        """Plain JSON data (floats written by ``repr``: exact round trips)."""
        s = self.structure
        return {"feature": s.feature.tolist(), "threshold": s.threshold.tolist(),
                "left": s.left.tolist(), "right": s.right.tolist(),
                "command": s.action.tolist(), "samples": s.samples.tolist(),
                "n_features": s.n_features, "values": self.values.tolist()}

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> CommandArrays:
        values = np.asarray(doc["values"], dtype=np.float64).reshape(len(doc["values"]), -1)
        structure = TreeArrays(
            np.asarray(doc["feature"], dtype=np.int64),
            np.asarray(doc["threshold"], dtype=np.float64),
            np.asarray(doc["left"], dtype=np.int64), np.asarray(doc["right"], dtype=np.int64),
            np.asarray(doc["command"], dtype=np.int64),
            np.asarray(doc["samples"], dtype=np.float64), int(doc["n_features"]), len(values))
        return cls(structure, values)


class CommandPopulation(ThresholdSets):
    """Threshold and command-table sets of one command tree, decided in one batch (the
    :class:`ibt.refine.by_return.Batch` protocol): row ``i`` is decided by ``members[i]``."""

    def __init__(self, arrays: CommandArrays, thresholds: np.ndarray, values: np.ndarray):
        super().__init__(arrays.structure, thresholds)
        self.values = np.asarray(values, dtype=np.float64).reshape(
            len(self.thresholds), *arrays.values.shape)

    def decide(self, features: np.ndarray, members: np.ndarray) -> np.ndarray:
        leaf = self.leaves(features, members)
        return self.values[members, self.structure.action[leaf]].astype(np.float32)


def _rounded(values: np.ndarray, task: Task, decimals: int) -> np.ndarray:
    """Command values rounded to ``decimals`` and clipped to the Box (what a BT writes)."""
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    return np.clip(np.round(values, decimals), low, high) + 0.0


def _cma_stage(arrays: CommandArrays, task: Task, spread: np.ndarray, config: RefineConfig,
               episodes: RefineEpisodes, rng: np.random.Generator, decimals: int
               ) -> tuple[CommandArrays, dict]:
    """CMA-ES on thresholds and command values (:func:`ibt.refine.by_return.cma_search`):
    thresholds in their feature's spread, values in :data:`VALUE_SCALE` of the Box, each
    candidate's values clipped to the Box and rounded as a BT writes them."""
    splits = np.flatnonzero(~arrays.structure.is_leaf)
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    base_t, base_v = arrays.structure.threshold.copy(), arrays.values.copy()
    scale = np.concatenate([spread[arrays.structure.feature[splits]],
                            np.tile(VALUE_SCALE * (high - low), len(base_v))])

    def members(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z = np.atleast_2d(z) * scale
        t = np.repeat(base_t[None, :], len(z), axis=0)
        t[:, splits] = base_t[splits] + z[:, :len(splits)]
        v = np.clip(base_v[None] + z[:, len(splits):].reshape(len(z), *base_v.shape), low, high)
        return t, _rounded(v, task, decimals)

    best, info = cma_search(len(scale), config, episodes, rng,
                            lambda z: CommandPopulation(arrays, *members(z)))
    if best is None:
        return arrays, info
    t, v = members(best)
    return arrays.with_parameters(t[0], v[0]), info


@dataclass
class CommandRefinement(RefinementRecord[CommandArrays]):
    """A command-tree refinement's record: each stage's result and the chosen tree."""

    @staticmethod
    def candidate_from_doc(doc: dict[str, Any]) -> CommandArrays:
        return CommandArrays.from_doc(doc)


def refine_commands(tree: Any, task: Task, config: RefineConfig, seed: int = 0, *,
                    decimals: int = 2, progress: bool = True) -> CommandRefinement:
    """Refine a command tree's thresholds and command values on ``task``'s return (only the
    ``cma`` stages of ``config`` apply: shape and command ids stay). ``tree``: a
    :class:`CommandArrays` or a :class:`ibt.synth.commands.CommandTree`; command values are
    rounded to ``decimals`` (:data:`ibt.synth.commands.DECIMALS`). See the module docstring."""
    if not task.continuous:
        raise ValueError(f"{task.name} has discrete actions: refine its tree with "
                         "ibt.refine.by_return.refine")
    unknown = [s for s in config.stages if s != "cma"]
    if unknown:
        raise ValueError(f"a command tree is refined by CMA-ES stages only, not {unknown}")
    source = tree if isinstance(tree, CommandArrays) else CommandArrays.from_command_tree(tree)
    source = CommandArrays(source.structure, _rounded(source.values, task, decimals)).simplified()
    if source.structure.n_features != task.n_features:
        raise ValueError(f"the tree reads {source.structure.n_features} features, {task.name} "
                         f"has {task.n_features}")
    rng = np.random.default_rng(seed)
    record = CommandRefinement(task.name, seed, config.as_params(), candidates=[source])
    episodes = RefineEpisodes.opened(task, seed, config, "refine commands", progress)
    bar = episodes.bar
    spread = visited_spread(task, source.actions, episodes)
    current = source
    for name in config.stages:
        current, info = _cma_stage(current, task, spread, config, episodes, rng, decimals)
        current = current.simplified()
        record.candidates.append(current)
        record.stages.append({"stage": name, "leaves": current.n_leaves,
                              "episodes_used": episodes.used, **info})
        bar.set_postfix(stage=name, leaves=current.n_leaves)
    bar.close()
    scores = held_out_means(episodes, [CommandPopulation(a, a.structure.threshold, a.values)
                                       for a in record.candidates], config, seed)
    record.best_index = max(range(len(scores)), key=lambda i: (scores[i], -i))
    return close_record(record, scores, episodes)
