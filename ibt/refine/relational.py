"""Refinement by return of relational trees, by :func:`ibt.refine.by_return.refine`.

A relational tree is an axis-aligned tree over augmented columns (observed features, then the
derived ``w1 * x_i + w2 * x_j`` of its :class:`ibt.bt.linear.FeatureMap`). Refinement runs
unchanged on it when the rollouts feed augmented features: the
:class:`~ibt.distill.relational.AugmentedTask` is the task whose :meth:`features` appends the
derived columns (by the floating-point rule of :mod:`ibt.bt.linear`) and whose feature names and
box cover them. CMA-ES then tunes every
threshold, relational ones included, in units of its column's spread over visited states; the
leaf sweeps and pruning work as on any tree. The weights stay fixed (the learner picks them from
readable pairs; tuning them would make the tests harder to read).

``simplified()`` treats each derived column as a feature of its own: exact on every input, it
only misses cuts implied jointly by relational and axis tests (a larger tree, never a wrong
one).
"""

from __future__ import annotations

from typing import Any

from ibt.bt.linear import FeatureMap
from ibt.distill.relational import RelationalTreeClassifier, as_relational, augmented_task
from ibt.refine.by_return import Refinement, refine
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.settings import RefineConfig
from ibt.tasks.task import Task

FEATURE_MAP_KEY = "feature_map"  # where a relational refinement's record keeps its map


def refine_relational(tree: RelationalTreeClassifier, task: Task, config: RefineConfig,
                      seed: int = 0, *, progress: bool = True) -> Refinement:
    """:func:`ibt.refine.by_return.refine` of a relational tree on ``task``'s return; the
    record's ``config`` holds the feature map (plain data), read by :func:`best_tree`."""
    fmap = tree.feature_map_
    record = refine(TreeArrays.from_sklearn(tree), augmented_task(task, fmap), config, seed,
                    progress=progress)
    record.config[FEATURE_MAP_KEY] = fmap.to_json()
    return record


def feature_map_of_record(record: Refinement) -> FeatureMap | None:
    doc = record.config.get(FEATURE_MAP_KEY)
    return None if doc is None else FeatureMap.from_json(doc)


def best_tree(record: Refinement) -> Any:
    """A refinement's chosen tree: a :class:`RelationalTreeClassifier` when it refined one."""
    fmap = feature_map_of_record(record)
    tree = record.best_tree
    return tree if fmap is None else as_relational(tree, fmap)
