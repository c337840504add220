"""Structure search by return with relational tests: Imitation-BT+SR.

:func:`ibt.refine.structure.evolve` searches a tree's splits, features, thresholds and leaves on
return. Here it searches over *augmented* columns: the observed features and every candidate
``w1 * x_i + w2 * x_j`` of the relational learner (:func:`ibt.distill.relational.candidate_map`:
every pair of non-binary features with every weight pair of
:data:`ibt.bt.linear.DEFAULT_WEIGHTS`). Nothing else changes: the same seed trees (axis-aligned
trees read as trees over the augmented columns; a relational seed tree, e.g. the relational
learner's, read with its derived columns added to the candidates where they are not among
them: :func:`seed_columns`), mutations, budget, common random episodes and
held-out choice; "change a feature" and "grow" may now pick a relational column, and the
expert's CART stump picks whichever column separates its labels best. So a comparison with
Imitation-BT+S at the same leaf limit and budget measures what relational tests add.

Which features are binary (a leg's ground contact gains nothing from a weighted sum) is read
from the states the first seed tree visits on a few episodes of a seed block of their own
(:data:`CANDIDATE_SEED_BASE`), not counted in the budget. The winner keeps only the derived
columns it uses (:func:`compact`) and becomes a
:class:`ibt.distill.relational.RelationalTreeClassifier`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ibt.bt.linear import DEFAULT_WEIGHTS, FeatureMap
from ibt.distill.relational import (
    RelationalTreeClassifier,
    as_relational,
    candidate_map,
    feature_map_of,
    scaled_candidate_map,
)
from ibt.evaluate.rollouts import REFINE_SEED_BASE, rollout
from ibt.refine.relational import FEATURE_MAP_KEY, augmented_task
from ibt.refine.structure import Evolution, evolve, reselect
from ibt.refine.tree_arrays import LEAF, TreeArrays
from ibt.tasks.settings import EvolveConfig
from ibt.tasks.task import Task

#: the episodes that find the binary features: in run seed 0's block of refinement seeds,
#: beyond every budget's reach (refinement below 100,000, the search from 500,000 to 600,000)
CANDIDATE_SEED_BASE = REFINE_SEED_BASE + 900_000
CANDIDATE_EPISODES = 8


def widen(tree: TreeArrays, width: int) -> TreeArrays:
    """An axis-aligned tree over observed features as the same tree over ``width`` augmented
    columns (observed columns come first, so nothing is renumbered)."""
    if tree.n_features > width:
        raise ValueError(f"a tree of {tree.n_features} features cannot be read as {width}")
    return renumber(tree, {}, width)


def renumber(tree: TreeArrays, column: Mapping[int, int], width: int) -> TreeArrays:
    """The same tree over ``width`` columns, each split reading ``column[c]`` where it read
    ``c`` (a column not in ``column`` keeps its number)."""
    split = tree.left != LEAF
    feature = np.array([column.get(int(c), int(c)) if s else int(c)
                        for c, s in zip(tree.feature, split, strict=True)], dtype=np.int64)
    return TreeArrays(feature, tree.threshold, tree.left, tree.right, tree.action,
                      tree.samples, width, tree.n_actions)


def compact(tree: TreeArrays, feature_map: FeatureMap) -> tuple[TreeArrays, FeatureMap]:
    """The tree over only the derived columns it tests, renumbered in the map's order."""
    n_axis = feature_map.n_features
    split = tree.left != LEAF
    used = sorted({int(c) for c in tree.feature[split] if c >= n_axis})
    small = FeatureMap(n_axis, tuple(feature_map.form(c) for c in used))
    return renumber(tree, {c: n_axis + k for k, c in enumerate(used)}, small.width), small


def search_map(task: Task, source: TreeArrays | Any,
               weights: Sequence[tuple[float, float]] = DEFAULT_WEIGHTS,
               scaled: bool = False) -> FeatureMap:
    """The candidate derived columns: every pair of the features that take more than two
    values on the states ``source`` (arrays or a fitted tree, relational or not) visits, with
    every weight pair (``scaled``: the second weight scaled by the pair's ratio of spreads on
    those states, :func:`ibt.distill.relational.scaled_candidate_map`)."""
    tree = source.to_sklearn() if isinstance(source, TreeArrays) else source
    seeds = [CANDIDATE_SEED_BASE + i for i in range(CANDIDATE_EPISODES)]
    result = rollout(task, lambda obs: tree.predict(task.features(obs)), seeds,
                     n_envs=CANDIDATE_EPISODES, collect=True)
    states = np.concatenate([task.features(o) for o in result.obs])
    return (scaled_candidate_map if scaled else candidate_map)(states, weights)


def seed_columns(sources: Sequence[TreeArrays | Any], candidates: FeatureMap
                 ) -> tuple[FeatureMap, list[TreeArrays]]:
    """The search's columns and its seed trees over them: ``candidates``, then each relational
    seed tree's derived columns that are not among them (in the seeds' order); axis-aligned
    seeds (arrays or fitted trees) are widened, relational ones renumbered. Without relational
    seeds the columns are ``candidates`` unchanged."""
    maps = [None if isinstance(s, TreeArrays) else feature_map_of(s) for s in sources]
    forms = list(candidates.forms)
    for own in maps:
        forms += [f for f in (own.forms if own is not None else ()) if f not in forms]
    columns = FeatureMap(candidates.n_features, tuple(forms))
    trees = []
    for source, own in zip(sources, maps, strict=True):
        arrays = source if isinstance(source, TreeArrays) else TreeArrays.from_sklearn(source)
        if own is None:
            trees.append(widen(arrays, columns.width))
            continue
        trees.append(renumber(arrays, {c: columns.n_features + forms.index(own.form(c))
                                       for c in range(own.n_features, own.width)},
                              columns.width))
    return columns, trees


def evolve_relational(sources: Sequence[TreeArrays | Any], task: Task, config: EvolveConfig,
                      seed: int = 0, *, expert: object | None = None,
                      weights: Sequence[tuple[float, float]] = DEFAULT_WEIGHTS,
                      scaled_weights: bool = False, progress: bool = True) -> Evolution:
    """:func:`ibt.refine.structure.evolve` over the observed features and the candidate
    relational columns (those of the states the first seed tree visits, and the relational
    seed trees' own); the record's ``config`` holds the columns' map (plain data)."""
    sources = [s if isinstance(s, TreeArrays) or feature_map_of(s) is not None
               else TreeArrays.from_sklearn(s) for s in sources]
    fmap, seeds = seed_columns(sources, search_map(task, sources[0], weights, scaled_weights))
    wide = augmented_task(task, fmap)
    record = evolve(seeds, wide, config, seed, expert=expert, progress=progress)
    record.config[FEATURE_MAP_KEY] = fmap.to_json()
    return record


def reselect_relational(record: Evolution, task: Task, selection_episodes: int) -> Evolution:
    """:func:`ibt.refine.structure.reselect` of a relational search (its finalists read the
    augmented columns of the record's candidate map)."""
    wide = augmented_task(task, FeatureMap.from_json(record.config[FEATURE_MAP_KEY]))
    return reselect(record, wide, selection_episodes)


def winner(record: Evolution) -> RelationalTreeClassifier:
    """The search's chosen tree as a relational tree over only the derived columns it tests."""
    fmap = FeatureMap.from_json(record.config[FEATURE_MAP_KEY])
    tree, small = compact(record.best, fmap)
    return as_relational(tree.to_sklearn(), small)


__all__ = ["compact", "evolve_relational", "renumber", "reselect_relational", "search_map",
           "seed_columns", "widen", "winner"]
