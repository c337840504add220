"""Synthesis and verification of relational trees.

A :class:`~ibt.distill.relational.RelationalTreeClassifier` is CART on *augmented* rows: the
observed features followed by derived columns ``z_k = w1 * x[i] + w2 * x[j]``
(:class:`~ibt.bt.linear.FeatureMap`). Every synthesiser works on it unchanged, on the augmented
space:

1. :func:`augmented_view` gives the plain scikit-learn tree behind it (same ``tree_``), and
   :func:`~ibt.distill.relational.augmented_task` a task whose features are the augmented
   columns (named ``x - vx``; its box bounds each derived column by interval arithmetic);
2. the synthesiser runs on those (so Espresso's implication don't-cares between tests of one
   linear form come for free: they test one column), and verifies its BT there;
3. :func:`rewrite` turns every condition on a derived column ``k`` into the relational
   condition ``form(k) op T`` with ``T = exact_threshold(t)`` (the floating-point rule of
   :mod:`ibt.bt.linear`: the double ``z <= T`` decides as the tree's ``float32(z) <= t``);
4. :func:`verify_relational` checks the BT in observed space against ``tree.predict``: one
   state inside every leaf region (a polytope; a linear program finds it, inside the task's box
   where it can), the last state on each side of every test of the region's path, and random
   states from the task's box.

:func:`synthesise` is the whole route; :class:`ibt.synth.registry.Synthesiser` and the built-in
synthesisers call it when given a relational tree, so the CLI, the grid, the front and the
recommendation take relational trees through their usual entry points.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.linear import FeatureMap, exact_threshold
from ibt.bt.model import BehaviorTree, Condition, Fallback, Inverter, Node, Sequence
from ibt.bt.polytope import Test, crossing_rows, find_state
from ibt.distill.relational import augmented_task, feature_map_of
from ibt.synth.rules import leaf_paths
from ibt.tasks.catalogue import Task


def is_relational(tree: Any) -> bool:
    """Is ``tree`` a fitted relational tree (one with a feature map)?"""
    return feature_map_of(tree) is not None


def augmented_view(tree: Any) -> DecisionTreeClassifier:
    """The plain scikit-learn tree on augmented rows behind a relational tree (it shares the
    fitted ``tree_``; its ``predict`` takes augmented rows)."""
    view = DecisionTreeClassifier.__new__(DecisionTreeClassifier)
    view.__dict__.update({k: v for k, v in tree.__dict__.items() if k != "feature_map_"})
    return view


def rewrite(node: Node, feature_map: FeatureMap) -> Node:
    """Every condition on a derived column as its relational condition, ``T`` exact."""
    if isinstance(node, Condition):
        if not feature_map.is_derived(node.feature):
            return node
        return Condition.relational(feature_map.form(node.feature), node.op,
                                    exact_threshold(node.threshold))
    if isinstance(node, Inverter):
        return Inverter(rewrite(node.child, feature_map))
    if isinstance(node, Fallback | Sequence):  # Selector too
        return type(node)(tuple(rewrite(child, feature_map) for child in node.children))
    return node


def synthesise(function: Callable[..., Any], tree: Any, task: Task, **options: Any) -> Any:
    """``function(tree, task, **options)`` (a synthesiser) for a relational tree: on the
    augmented space, rewritten into relational conditions and verified in observed space
    unless ``check=False``. The :class:`~ibt.synth.imitation.Synthesis` keeps its rule sets in
    augmented columns and says so (``feature_map``)."""
    feature_map = feature_map_of(tree)
    assert feature_map is not None
    wide = augmented_task(task, feature_map, discrete_state=False, integer_features=False)
    result = function(augmented_view(tree), wide, **options)
    bt = result.bt
    relational = BehaviorTree(rewrite(bt.root, feature_map), task.feature_names,
                              task.action_names, task.value_labels, bt.commands)
    out = replace(result, bt=relational, feature_map=feature_map)
    if options.get("check", True):
        verify_relational(relational, tree, task, seed=options.get("rng_seed", 0))
    return out


# --------------------------------------------------------------------------- verification
@dataclass(frozen=True)
class RelationalCheck:
    """What :func:`verification_states` tried: leaf regions, how many got a state inside
    (the others are empty in observed space, or too thin for a float32 state), the states on
    both sides of tests, and random states."""

    states: np.ndarray
    regions: int
    regions_found: int
    boundary_states: int
    random_states: int


def path_tests(tree: Any) -> list[tuple[list[Test], int]]:
    """Each leaf's path as tests in observed space (derived columns as their forms with
    exact thresholds), with the leaf's action."""
    feature_map = feature_map_of(tree)
    assert feature_map is not None
    out = []
    for path in leaf_paths(tree):
        tests: list[Test] = []
        for lit in path.term:
            if feature_map.is_derived(lit.feature):
                tests.append((feature_map.form(lit.feature), exact_threshold(lit.threshold),
                              lit.le))
            else:
                tests.append((lit.feature, lit.threshold, lit.le))
        out.append((tests, path.action))
    return out


def verification_states(tree: Any, task: Task, n_random: int = 20_000, seed: int = 0
                        ) -> RelationalCheck:
    """States that test a BT against its relational tree (see the module docstring)."""
    rows: list[np.ndarray] = []
    found = boundary = 0
    paths = path_tests(tree)
    for tests, _ in paths:
        state = find_state(task.n_features, tests, task.low, task.high)
        if state is None:
            continue
        found += 1
        rows.append(state)
        for what, threshold, _le in tests:
            edges = crossing_rows(what, threshold, state)
            boundary += len(edges)
            rows.extend(edges)
    random = task.sample_features(n_random, np.random.default_rng(seed)).astype(np.float32)
    states = np.concatenate([np.asarray(rows, dtype=np.float32).reshape(-1, task.n_features),
                             random])
    return RelationalCheck(states, len(paths), found, boundary, len(random))


def verify_relational(bt: BehaviorTree, tree: Any, task: Task, *, seed: int = 0,
                      n_random: int = 20_000) -> int:
    """Raise :class:`~ibt.synth.imitation.NotEquivalentError` unless ``bt`` decides as the
    relational ``tree`` (its ``predict`` on observed rows) on every state of
    :func:`verification_states`; returns how many states were checked."""
    from ibt.synth.imitation import check_agreement

    states = verification_states(tree, task, n_random=n_random, seed=seed).states
    return check_agreement(bt, states, np.asarray(tree.predict(states)).astype(np.int64),
                           "relational tree")
