"""Exact decision lists: the list's entries, its regions as boxes, the exactness check, and
simplification (the decision-list synthesis, :mod:`ibt.synth.decision_list`).

A decision list is a flat list of ``(term, action)`` entries: a state takes the action of the
first entry whose term holds. A tree's leaves are boxes (``lo < x <= hi`` on every feature, the
only shape ``<=``/``>`` tests make); :func:`decides_like` checks by interval arithmetic on those
boxes, not by sampling, that a list decides as the tree on every real state, and
:func:`simplify` drops entries, then literals, while that check holds. The search, the
factoring and the simplification share the wall-clock safety net (:class:`SearchTimeout`),
defined here, the lowest of the decision-list modules.
"""

from __future__ import annotations

import time

import numpy as np

from ibt.synth.rules import Literal, Term

Entry = tuple[Term, int]  # a decision-list entry: if term holds, decide action


class SearchTimeout(Exception):
    """The wall-clock safety net of the search was hit."""


# -------------------------------------------------------------- exact region arithmetic
# A box is (lo, hi) over every feature: lo < x <= hi (the only shape ``<=``/``>`` tests make).
Box = tuple[tuple[float, ...], tuple[float, ...]]


def _term_bounds(term: Term) -> dict[int, tuple[float, float]]:
    bounds: dict[int, tuple[float, float]] = {}
    for lit in term:
        lo, hi = bounds.get(lit.feature, (-np.inf, np.inf))
        bounds[lit.feature] = (lo, min(hi, lit.threshold)) if lit.le else (
            max(lo, lit.threshold), hi)
    return bounds


def term_box(term: Term, n_features: int) -> Box:
    """The region of ``term`` as a box (lower bounds, upper bounds), infinite where untested."""
    lo = [-np.inf] * n_features
    hi = [np.inf] * n_features
    for f, (a, b) in _term_bounds(term).items():
        lo[f], hi[f] = a, b
    return tuple(lo), tuple(hi)


def _meets(box: Box, bounds: dict[int, tuple[float, float]]) -> bool:
    lo, hi = box
    return all(max(lo[f], a) < min(hi[f], b) for f, (a, b) in bounds.items())


def _subtract(box: Box, bounds: dict[int, tuple[float, float]]) -> list[Box]:
    """``box`` minus the region of ``bounds``, as disjoint boxes."""
    if not _meets(box, bounds):
        return [box]
    lo, hi = list(box[0]), list(box[1])
    out: list[Box] = []
    for f, (a, b) in bounds.items():
        if a > lo[f]:  # the slab lo < x <= a lies outside
            out.append((tuple(lo), (*hi[:f], a, *hi[f + 1:])))
            lo[f] = a
        if b < hi[f]:  # the slab b < x <= hi lies outside
            out.append(((*lo[:f], b, *lo[f + 1:]), tuple(hi)))
            hi[f] = b
    return out


def decides_like(entries: list[Entry], leaves: list[tuple[Box, int]]) -> bool:
    """Does the decision list decide exactly as the leaves on every real state?

    ``leaves`` partition the space (a tree's leaf boxes). Exact: no sampling. The last entry
    must be unguarded (empty term) for the list to decide everywhere.
    """
    bounds = [_term_bounds(term) for term, _ in entries]
    for box, action in leaves:
        residual = [box]
        for (_, act), b in zip(entries, bounds, strict=True):
            if act != action and any(_meets(piece, b) for piece in residual):
                return False
            residual = [p for piece in residual for p in _subtract(piece, b)]
            if not residual:
                break
        if residual:
            return False
    return True


def tighten(term: Term) -> Term:
    """Drop literals implied by another of the same term (``x <= 1`` beside ``x <= 0.5``)."""
    bounds = _term_bounds(term)
    out: list[Literal] = []
    for lit in term:
        lo, hi = bounds[lit.feature]
        keep = lit.threshold == hi if lit.le else lit.threshold == lo
        if keep and lit not in out:
            out.append(lit)
    return tuple(out)


# ----------------------------------------------------------------------- simplification
def simplify(entries: list[Entry], leaves: list[tuple[Box, int]],
             deadline: float | None = None) -> list[Entry]:
    """Drop entries, then literals, one at a time while the list stays exact (fixed order);
    :class:`SearchTimeout` once ``time.monotonic()`` passes ``deadline``."""
    def late() -> bool:
        return deadline is not None and time.monotonic() > deadline

    entries = list(entries)
    changed = True
    while changed:
        changed = False
        i = 0
        while i < len(entries) - 1:
            if late():
                raise SearchTimeout
            trial = entries[:i] + entries[i + 1:]
            if decides_like(trial, leaves):
                entries, changed = trial, True
                continue
            i += 1
        for i in range(len(entries) - 1):
            term, action = entries[i]
            for lit in term:
                if late():
                    raise SearchTimeout
                shorter = tuple(x for x in term if x != lit)
                trial = [*entries[:i], (shorter, action), *entries[i + 1:]]
                if decides_like(trial, leaves):
                    entries, term, changed = trial, shorter, True
    return entries


__all__ = ["Box", "Entry", "SearchTimeout", "decides_like", "simplify"]
