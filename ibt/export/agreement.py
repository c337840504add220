"""The states an executor is checked on against a BT, chosen from the BT itself.

A BT with axis-aligned conditions is a decision tree in disguise: :func:`leaf_regions` splits
the feature space into the boxes on which it decides one action. :func:`agreement_states` puts a
state inside every box, the float32 values just below, at and above every bound and threshold
(:func:`threshold_neighbours`: where a float32 comparison can flip), random states from the
task's box and, for a discrete-state task, the whole state space; a BT with relational
conditions gets its polytopes' states from :mod:`ibt.bt.polytope`. BehaviorTree.CPP
(:mod:`ibt.export.engine`) and every other executor are checked on these states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ibt.bt.model import (
    NO_DECISION,
    Action,
    BehaviorTree,
    Condition,
    Inverter,
    Node,
    iterate,
)
from ibt.bt.model import Sequence as SequenceNode
from ibt.tasks.catalogue import Task


# ----------------------------------------------------------------------- checking states
@dataclass(frozen=True)
class Region:
    """A box ``lo < x <= hi`` (per feature; infinite bounds allowed) where the BT decides
    ``action``."""

    lo: np.ndarray
    hi: np.ndarray
    action: int


class _Split(Exception):
    def __init__(self, feature: int, threshold: float) -> None:
        self.feature, self.threshold = feature, threshold


def _status(node: Node, lo: np.ndarray, hi: np.ndarray) -> tuple[bool, int]:
    """Success and decision of ``node`` on every point of the box, or :class:`_Split`."""
    if isinstance(node, Condition):
        f, t = node.feature, node.threshold
        if hi[f] <= t:
            below = True
        elif lo[f] >= t:
            below = False
        else:
            raise _Split(f, t)
        return below == (node.op == "<="), NO_DECISION
    if isinstance(node, Action):
        return True, node.action
    if isinstance(node, Inverter):
        ok, decision = _status(node.child, lo, hi)
        return not ok, decision
    want = isinstance(node, SequenceNode)  # a sequence goes on while its children succeed
    decision = NO_DECISION
    for child in node.children:
        ok, chosen = _status(child, lo, hi)
        if decision == NO_DECISION:
            decision = chosen
        if ok != want:
            return not want, decision
    return want, decision


def leaf_regions(bt: BehaviorTree) -> list[Region]:
    """The boxes on which ``bt`` decides one action: the leaves of the decision tree it is.

    Evaluates the BT on a box and splits the box at the first condition whose outcome the box
    does not fix, until every box is decided (like ``leaf_paths`` of a CART tree).
    """
    if bt.relational_count:
        raise ValueError("leaf_regions takes axis-aligned BTs; the regions of a BT with "
                         "relational conditions are polytopes: ibt.bt.polytope.bt_regions")
    n = len(bt.feature_names)
    stack = [(np.full(n, -np.inf), np.full(n, np.inf))]
    regions: list[Region] = []
    while stack:
        lo, hi = stack.pop()
        try:
            _, action = _status(bt.root, lo, hi)
        except _Split as split:
            left_hi, right_lo = hi.copy(), lo.copy()
            left_hi[split.feature] = right_lo[split.feature] = split.threshold
            stack.append((right_lo, hi))
            stack.append((lo, left_hi))
            continue
        regions.append(Region(lo, hi, action))
    return regions


def _down(x: float) -> np.float32:
    """The largest float32 value at or below ``x``."""
    v = np.float32(x)
    return np.nextafter(v, np.float32(-np.inf)) if float(v) > x else v


def _up(x: float) -> np.float32:
    """The smallest float32 value above ``x``."""
    v = np.float32(x)
    return np.nextafter(v, np.float32(np.inf)) if float(v) <= x else v


def threshold_neighbours(threshold: float) -> list[float]:
    """The float32 values around ``t`` as the executor compares them: the two largest at or
    below it and the two smallest above it."""
    at, above = _down(threshold), _up(threshold)
    return [float(np.nextafter(at, np.float32(-np.inf))), float(at), float(above),
            float(np.nextafter(above, np.float32(np.inf)))]


def _inside(lo: float, hi: float, low: float, high: float, integer: bool) -> float | None:
    """A float32 value ``v`` with ``lo < v <= hi``, inside the task's box where they overlap
    (an integer for integer features), else as ``ibt.synth.rules.leaf_witnesses`` picks; ``None``
    when no float32 value lies in the interval."""
    if integer:
        first = max(np.floor(lo) + 1, np.ceil(low))
        last = min(np.floor(hi), np.floor(high))
        if first <= last:
            return float((first + last) // 2)
    a, b = max(lo, low), min(hi, high)
    if a <= b:
        value = (a + b) / 2
    elif np.isfinite(lo) and np.isfinite(hi):
        value = (lo + hi) / 2
    else:
        value = hi - 1.0 if np.isfinite(hi) else lo + 1.0
    for v in (np.float32(value), _up(lo), _down(hi)):
        if lo < float(v) <= hi:
            return float(v)
    return None


def agreement_states(bt: BehaviorTree, task: Task, n_random: int = 10_000,
                     seed: int = 0) -> np.ndarray:
    """States to check an executor against ``bt`` on (float32 rows).

    A point inside every leaf region (:func:`leaf_regions`); for each, the bounding features set
    to the float32 values just below, at and above the bound (:func:`threshold_neighbours`);
    every threshold's neighbours once more in a random state (conditions no region bounds);
    ``n_random`` random states from the task's box; the whole state space of a discrete task.
    """
    if bt.relational_count:  # polytope regions: ibt.bt.polytope.agreement_rows
        from ibt.bt.polytope import agreement_rows

        random = task.sample_features(n_random, np.random.default_rng(seed))
        return agreement_rows(bt, task.low, task.high, random, seed=seed)
    low, high = np.asarray(task.low, dtype=np.float64), np.asarray(task.high, dtype=np.float64)
    integer = task.integer_features or task.discrete_state
    rng = np.random.default_rng(seed)
    rows: list[np.ndarray] = []
    for region in leaf_regions(bt):
        point = [_inside(region.lo[f], region.hi[f], low[f], high[f], integer)
                 for f in range(len(low))]
        if any(v is None for v in point):  # no float32 value in the box
            continue
        base = np.asarray(point, dtype=np.float64)
        rows.append(base)
        for f in range(len(low)):
            for bound in (region.lo[f], region.hi[f]):
                if np.isfinite(bound):
                    for value in threshold_neighbours(bound):
                        edge = base.copy()
                        edge[f] = value
                        rows.append(edge)
    random = task.sample_features(n_random, rng)
    for node in iterate(bt.root):
        if isinstance(node, Condition):
            for value in threshold_neighbours(node.threshold):
                edge = random[rng.integers(len(random))].astype(np.float64)
                edge[node.feature] = value
                rows.append(edge)
    parts = [np.asarray(rows, dtype=np.float32).reshape(-1, len(low)), random]
    if task.discrete_state:
        parts.append(np.arange(task.low[0], task.high[0] + 1, dtype=np.float32)[:, None])
    return np.concatenate(parts)
