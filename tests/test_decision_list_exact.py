"""Exact decision lists (:mod:`ibt.synth.decision_list_exact`) against brute force: on features
whose thresholds come from a small set, every state behaves as one of finitely many
representatives (each threshold and one value above them all), so "decides as the tree on
every real state" can be checked exhaustively, and the interval arithmetic must agree."""

from __future__ import annotations

import itertools
import random
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.synth.decision_list_exact import (
    Entry,
    SearchTimeout,
    decides_like,
    simplify,
    term_box,
    tighten,
)
from ibt.synth.rules import Literal, Term

N = 3
THRESHOLDS = (-0.5, 0.0, 0.5)
# every state decides as one of these: the cell (t_{k-1}, t_k] as t_k, above 0.5 as 1.0
GRID = np.asarray(list(itertools.product((*THRESHOLDS, 1.0), repeat=N)))
ACTIONS = 3


def holds(term: Term, x: np.ndarray) -> bool:
    return all((x[lit.feature] <= lit.threshold) == lit.le for lit in term)


def list_decision(entries: list[Entry], x: np.ndarray) -> int | None:
    return next((a for t, a in entries if holds(t, x)), None)


def random_leaves(rng: random.Random, max_depth: int) -> list[tuple[Term, int]]:
    """A random tree's leaves as (path, action): every split strictly inside its region, so
    no leaf is empty (as in a fitted tree)."""
    def grow(term: Term, lo: list[float], hi: list[float], depth: int
             ) -> list[tuple[Term, int]]:
        cuts = [(f, t) for f in range(N) for t in THRESHOLDS if lo[f] < t < hi[f]]
        if depth == 0 or not cuts or rng.random() < 0.25:
            return [(term, rng.randrange(ACTIONS))]
        f, t = rng.choice(cuts)
        left_hi, right_lo = list(hi), list(lo)
        left_hi[f], right_lo[f] = t, t
        return (grow((*term, Literal(f, t, True)), lo, left_hi, depth - 1)
                + grow((*term, Literal(f, t, False)), right_lo, hi, depth - 1))
    return grow((), [-np.inf] * N, [np.inf] * N, max_depth)


def random_term(rng: random.Random, max_len: int = 3) -> Term:
    return tuple(Literal(rng.randrange(N), rng.choice(THRESHOLDS), rng.random() < 0.5)
                 for _ in range(rng.randrange(max_len + 1)))


def boxes(leaves: list[tuple[Term, int]]):
    return [(term_box(t, N), a) for t, a in leaves]


def exact_list(rng: random.Random, leaves: list[tuple[Term, int]]) -> list[Entry]:
    """An exact list with redundancy: the leaves in a random order, the last as the unguarded
    default, with repeated and implied literals and entries shadowed by earlier ones."""
    entries: list[Entry] = []
    order = rng.sample(leaves, len(leaves))
    for term, action in order[:-1]:
        padded = list(term)
        for lit in term:
            if rng.random() < 0.3:
                padded.append(lit)  # repeated
            if rng.random() < 0.3 and lit.threshold != 0.5 and lit.le:
                padded.append(Literal(lit.feature, 0.5, True))  # implied by lit
        entries.append((tuple(padded), action))
        if rng.random() < 0.2:
            entries.append(((*term, *random_term(rng, 1)), rng.randrange(ACTIONS)))  # shadowed
    return [*entries, ((), order[-1][1])]  # the last leaf as the unguarded default


SEEDS = st.integers(0, 10**6)


@settings(max_examples=150, deadline=None)
@given(seed=SEEDS)
def test_term_box_is_the_region_of_its_term(seed):
    rng = random.Random(seed)
    term = random_term(rng, 5)
    lo, hi = term_box(term, N)
    for x in GRID:
        assert holds(term, x) == all(lo[f] < x[f] <= hi[f] for f in range(N))


@settings(max_examples=150, deadline=None)
@given(seed=SEEDS)
def test_tighten_keeps_the_region_and_only_the_literals_that_bound_it(seed):
    """Law: the tightened term is a subsequence of the term without repeats, with the same
    region, and each kept literal is its feature's tightest bound on its side."""
    term = random_term(random.Random(seed), 6)
    tight = tighten(term)
    assert term_box(tight, N) == term_box(term, N)
    assert len(set(tight)) == len(tight)
    rest = iter(term)
    assert all(lit in rest for lit in tight)  # in the term's order
    sides = [(lit.feature, lit.le) for lit in tight]
    assert len(set(sides)) == len(sides)


@settings(max_examples=200, deadline=None)
@given(seed=SEEDS, exact=st.booleans())
def test_decides_like_is_brute_force_on_every_state(seed, exact):
    """Law: ``decides_like`` holds exactly when the list decides as the tree on every
    representative state (so on every real state), for exact lists and random ones."""
    rng = random.Random(seed)
    leaves = random_leaves(rng, 4)
    if exact:
        entries = exact_list(rng, leaves)
        if rng.random() < 0.5:  # one literal or action changed: usually no longer exact
            i = rng.randrange(len(entries))
            term, action = entries[i]
            entries[i] = ((*term, *random_term(rng, 1)), (action + rng.randrange(2)) % ACTIONS)
    else:
        entries = [(random_term(rng), rng.randrange(ACTIONS)) for _ in range(rng.randrange(5))]
        if rng.random() < 0.8:
            entries.append(((), rng.randrange(ACTIONS)))
    truth = all(list_decision(entries, x) == list_decision(leaves, x) for x in GRID)
    assert decides_like(entries, boxes(leaves)) == truth


@settings(max_examples=80, deadline=None)
@given(seed=SEEDS)
def test_simplify_keeps_an_exact_list_exact_and_leaves_nothing_to_drop(seed):
    """Law: simplifying an exact list gives an exact list, made by dropping entries and
    literals only, its default untouched, from which no single entry (but the default) and no
    single literal can be dropped any more (a fixed point), so simplifying again changes
    nothing."""
    rng = random.Random(seed)
    leaves = random_leaves(rng, 4)
    entries = exact_list(rng, leaves)
    regions = boxes(leaves)
    short = simplify(entries, regions)
    assert all(list_decision(short, x) == list_decision(leaves, x) for x in GRID)
    assert short[-1] == entries[-1] and len(short) <= len(entries)
    rest = iter(entries)  # each kept entry is a later original one, of the same action
    assert all(any(a == b and set(t) <= set(u) for u, b in rest) for t, a in short)
    for i in range(len(short) - 1):
        assert not decides_like(short[:i] + short[i + 1:], regions)
        term, action = short[i]
        for lit in term:
            fewer = tuple(x for x in term if x != lit)
            assert not decides_like([*short[:i], (fewer, action), *short[i + 1:]], regions)
    assert simplify(short, regions) == short


def test_simplify_drops_entries_then_literals_in_a_fixed_order():
    """Two shadowed entries: the first that can go goes first (from the end, the duplicated
    one would go, then the first), and a literal goes with its repeats."""
    x_le, x_gt = Literal(0, 0.0, True), Literal(0, 0.0, False)
    y_le = Literal(1, 0.0, True)
    leaves = boxes([((x_le,), 0), ((x_gt,), 1)])
    entries = [((x_le, y_le), 0), ((x_le,), 0), ((x_le, x_le), 0), ((), 1)]
    assert simplify(entries, leaves) == [((x_le, x_le), 0), ((), 1)]
    assert simplify([((y_le, x_le, y_le), 0), ((), 1)], leaves) == [((x_le,), 0), ((), 1)]


def test_simplify_keeps_to_its_deadline():
    leaves = [((Literal(0, 0.0, True),), 0), ((Literal(0, 0.0, False),), 1)]
    entries = [((Literal(0, 0.0, True), Literal(1, 0.5, True)), 0),
               ((Literal(0, 0.0, True),), 0), ((), 1)]
    regions = boxes(leaves)
    with pytest.raises(SearchTimeout):
        simplify(entries, regions, deadline=time.monotonic() - 1.0)
    assert (simplify(entries, regions, deadline=time.monotonic() + 3600.0)
            == simplify(entries, regions))
