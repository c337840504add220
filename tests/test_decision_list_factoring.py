"""Factoring a flat decision list into a nested BT (:mod:`ibt.synth.decision_list_factoring`):
it decides as the list on every state (brute force over representative states, as in
:mod:`tests.test_decision_list_exact`), its sizes are the BT's node counts, it is never larger
than the list or its runs of one action, and it finds the factorings worked out by hand."""

from __future__ import annotations

import itertools
import random

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.executors import decide_batch
from ibt.bt.model import Action, Condition, Fallback, Selector, Sequence, iterate
from ibt.synth.decision_list_exact import Entry
from ibt.synth.decision_list_factoring import (
    Factorer,
    compose_node,
    factor,
    guarded_action,
    root_selector,
)
from ibt.synth.rules import Literal, Term

N = 3
THRESHOLDS = (-0.5, 0.0, 0.5)
GRID = np.asarray(list(itertools.product((*THRESHOLDS, 1.0), repeat=N)), dtype=np.float32)
A, B, C, D, E = (Literal(0, 0.0, True), Literal(1, 0.0, True), Literal(2, 0.0, True),
                 Literal(1, 0.5, False), Literal(2, -0.5, False))


def cond(lit: Literal) -> Condition:
    return Condition(lit.feature, lit.op, lit.threshold)


def list_decisions(entries: list[Entry]) -> np.ndarray:
    def one(x: np.ndarray) -> int:
        return next(a for t, a in entries
                    if all((x[lit.feature] <= lit.threshold) == lit.le for lit in t))
    return np.asarray([one(x) for x in GRID])


def random_list(rng: random.Random) -> list[Entry]:
    """Entries sharing literals and actions often (a small alphabet), then a default."""
    alphabet = (A, B, C, D, E)

    def term() -> Term:
        return tuple(dict.fromkeys(rng.choice(alphabet) for _ in range(rng.randrange(1, 4))))
    n = rng.randrange(1, 8)
    return [*((term(), rng.randrange(3)) for _ in range(n)), ((), rng.randrange(3))]


def node_count(node) -> int:
    return sum(1 for _ in iterate(node))


@settings(max_examples=120, deadline=None)
@given(seed=st.integers(0, 10**6))
def test_the_factored_bt_decides_as_its_list_and_is_never_larger(seed):
    """Law: the factored BT decides as the flat list on every state; its size is its node
    count; it is no larger than the list written flat or by runs of one action."""
    entries = random_list(random.Random(seed))
    node = factor(entries)
    root = root_selector(node)
    assert np.array_equal(decide_batch(root, GRID), list_decisions(entries))
    assert node_count(root) == node.size + (node.kind != "fb")
    flat = compose_node("fb", [guarded_action([t], a, {}) for t, a in entries])
    runs = compose_node("fb", [guarded_action([t for t, _ in run], a, {}) for a, run in
                               itertools.groupby(entries, key=lambda e: e[1])])
    assert node.size <= min(flat.size, runs.size)
    assert Factorer().size(entries) == node.size


@settings(max_examples=120, deadline=None)
@given(seed=st.integers(0, 10**6))
def test_a_guarded_action_acts_where_one_of_its_terms_holds(seed):
    """Law: ``Sequence(OR of terms, action)`` acts exactly where a term holds, and the OR is
    no larger than written flat."""
    rng = random.Random(seed)
    terms = [t for t, _ in random_list(rng)[:-1]]
    node = guarded_action(terms, 1, {})
    root = root_selector(compose_node("fb", [node, guarded_action([()], 0, {})]))
    holds = [any(all((x[lit.feature] <= lit.threshold) == lit.le for lit in t) for t in terms)
             for x in GRID]
    assert np.array_equal(decide_batch(root, GRID), np.where(holds, 1, 0))
    flat = compose_node("seq", [compose_node("fb", [compose_node(
        "seq", [guarded_action([(lit,)], 0, {}).items[0] for lit in t]) for t in terms]),
        guarded_action([()], 1, {})])
    assert node.size <= flat.size


def test_hand_worked_factorings():
    # one action's OR shares its literal: a & (b | c)
    assert root_selector(factor([((A, B), 0), ((A, C), 0), ((), 1)])) == Selector((
        Sequence((cond(A), Fallback((cond(B), cond(C))), Action(0))), Action(1)))
    # an OR whose term is implied by another's: a | (a & b) is a
    assert guarded_action([(A,), (A, B)], 0, {}).size == 3
    assert root_selector(factor([((A,), 0), ((A, B), 0), ((), 1)])) == Selector((
        Sequence((cond(A), Action(0))), Action(1)))
    # four entries of two actions share a literal: tested once (17 nodes, flat 18)
    shared = [((A, B), 0), ((A, C), 1), ((A, D), 0), ((A, E), 1), ((), 2)]
    assert root_selector(factor(shared)) == Selector((
        Sequence((cond(A), Fallback((Sequence((cond(B), Action(0))),
                                     Sequence((cond(C), Action(1))),
                                     Sequence((cond(D), Action(0))),
                                     Sequence((cond(E), Action(1))))))),
        Action(2)))
    assert factor(shared).size == 17
    # a run of one action in the middle of a list: one Action, its OR in the terms' order
    run = [((B,), 1), ((A,), 0), ((C,), 0), ((D,), 0), ((), 2)]
    assert root_selector(factor(run)) == Selector((
        Sequence((cond(B), Action(1))),
        Sequence((Fallback((cond(A), cond(D), cond(C))), Action(0))),
        Action(2)))
    # one entry: the action alone under the root
    assert root_selector(factor([((), 4)])) == Selector((Action(4),))
    assert compose_node("seq", [compose_node("seq", [guarded_action([(A,)], 0, {})])]).size == 3
