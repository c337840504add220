"""Decision tree -> Action Template Library (ATL): one DNF rule set per action.

Each root-to-leaf path of a fitted scikit-learn tree is a conjunction of *literals*
``feature <= t`` (the left branch) or ``feature > t`` (the right branch); the ATL collects the
conjunctions of every leaf that predicts the same action. Pure data, no logic minimisation here
(that lives in :mod:`ibt.synth.logic`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.executors import as_features


@dataclass(frozen=True, order=True)
class Literal:
    """``x[feature] <= threshold`` when ``le`` else ``x[feature] > threshold``."""

    feature: int
    threshold: float
    le: bool

    @property
    def op(self) -> str:
        return "<=" if self.le else ">"

    def holds(self, x: np.ndarray) -> np.ndarray:
        column = as_features(x)[:, self.feature]
        return column <= self.threshold if self.le else column > self.threshold

    def negated(self) -> Literal:
        return Literal(self.feature, self.threshold, not self.le)


Term = tuple[Literal, ...]  # a conjunction; the empty term is "always true"
ATL = dict[int, list[Term]]  # action -> disjunction of terms


@dataclass(frozen=True)
class LeafPath:
    """One leaf of a tree: its conditions, its action and how many training samples reached it."""

    term: Term
    action: int
    samples: float


def leaf_paths(tree: DecisionTreeClassifier) -> list[LeafPath]:
    """Every leaf's path (literals in root-to-leaf order) and predicted action."""
    t = tree.tree_
    classes = np.asarray(tree.classes_)
    paths: list[LeafPath] = []
    stack: list[tuple[int, Term]] = [(0, ())]
    while stack:
        node, term = stack.pop()
        left, right = t.children_left[node], t.children_right[node]
        if left == right:  # leaf
            action = int(classes[int(np.argmax(t.value[node][0]))])
            paths.append(LeafPath(term, action, float(t.weighted_n_node_samples[node])))
            continue
        feature, threshold = int(t.feature[node]), float(t.threshold[node])
        stack.append((right, (*term, Literal(feature, threshold, le=False))))
        stack.append((left, (*term, Literal(feature, threshold, le=True))))
    return paths


def action_template_library(tree: DecisionTreeClassifier) -> ATL:
    """One DNF per action (actions no leaf predicts are absent)."""
    atl: ATL = {}
    for path in leaf_paths(tree):
        atl.setdefault(path.action, []).append(path.term)
    return dict(sorted(atl.items()))


def merge_thresholds(term: Term) -> Term:
    """Keep one literal per (feature, direction): ``x <= min`` and ``x > max``.

    ``x <= a and x <= b`` is ``x <= min(a, b)``; ``x > a and x > b`` is ``x > max(a, b)``.
    The result is sorted by feature, ``<=`` before ``>``.
    """
    upper: dict[int, float] = {}
    lower: dict[int, float] = {}
    for lit in term:
        if lit.le:
            upper[lit.feature] = min(upper.get(lit.feature, np.inf), lit.threshold)
        else:
            lower[lit.feature] = max(lower.get(lit.feature, -np.inf), lit.threshold)
    merged = [Literal(f, t, True) for f, t in upper.items()]
    merged += [Literal(f, t, False) for f, t in lower.items()]
    return tuple(sorted(merged, key=lambda lit: (lit.feature, not lit.le, lit.threshold)))


def literal_count(terms: list[Term]) -> int:
    """The paper's complexity heuristic k: literals summed over a rule set."""
    return sum(len(term) for term in terms)


def term_holds(term: Term, x: np.ndarray) -> np.ndarray:
    """Where a conjunction holds on a batch."""
    x = np.atleast_2d(x)
    out = np.ones(len(x), dtype=bool)
    for lit in term:
        out &= lit.holds(x)
    return out


def dnf_holds(terms: list[Term], x: np.ndarray) -> np.ndarray:
    """Where a disjunction of conjunctions holds on a batch."""
    x = np.atleast_2d(x)
    out = np.zeros(len(x), dtype=bool)
    for term in terms:
        out |= term_holds(term, x)
    return out


def leaf_witnesses(tree: DecisionTreeClassifier, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """A point inside every leaf region, plus points on each boundary (``x == t``).

    ``low``/``high`` bound each feature (infinite bounds allowed). Boundary points exercise the
    ``<=`` semantics, where an executor comparing in the wrong precision would go astray.
    """
    points = []
    for path in leaf_paths(tree):
        lo = np.array(low, dtype=np.float64)
        hi = np.array(high, dtype=np.float64)
        for lit in path.term:
            if lit.le:
                hi[lit.feature] = min(hi[lit.feature], lit.threshold)
            else:
                lo[lit.feature] = max(lo[lit.feature], lit.threshold)
        point = np.zeros(len(lo))
        both = np.isfinite(lo) & np.isfinite(hi)
        only_hi = ~np.isfinite(lo) & np.isfinite(hi)
        only_lo = np.isfinite(lo) & ~np.isfinite(hi)
        point[both] = (lo[both] + hi[both]) / 2
        point[only_hi] = hi[only_hi] - 1.0
        point[only_lo] = lo[only_lo] + 1.0
        points.append(point)
        for lit in path.term:  # the split point itself, as float32 sees it
            edge = point.copy()
            edge[lit.feature] = lit.threshold
            points.append(edge)
            nudged = point.copy()
            nudged[lit.feature] = np.nextafter(np.float32(lit.threshold), np.float32(np.inf))
            points.append(nudged)
    return np.asarray(points, dtype=np.float32)
