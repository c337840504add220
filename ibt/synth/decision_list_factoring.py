"""Factoring a decision list into a nested BT (the decision-list synthesis's last step,
:mod:`ibt.synth.decision_list`).

The algebraic factoring of logic synthesis, on a flat list of ``(term, action)`` entries:
consecutive entries of one action share one Action (``Sequence(Fallback(terms...), action)``,
the OR factored by shared literals, recursively), and consecutive entries sharing a literal
test it once (``Sequence(c, Fallback(rest...))``). :class:`Factorer` finds the smallest such
nesting by an interval dynamic programme; every rewriting keeps the list's decisions on every
state. It checks the search's deadline (:class:`ibt.synth.decision_list_exact.SearchTimeout`).
"""

from __future__ import annotations

import time
from typing import NamedTuple

from ibt.bt.model import Action, Condition, Fallback, Node, Selector, Sequence
from ibt.synth.decision_list_exact import Entry, SearchTimeout
from ibt.synth.rules import Literal, Term

# algebraic factoring of one action's OR: the OR_BRANCHING most shared literals are tried as
# divisors (recursively) for ORs of up to OR_BRANCHING_TERMS terms, the most shared one beyond
OR_BRANCHING = 3
OR_BRANCHING_TERMS = 12


class _N(NamedTuple):
    """A BT node during the search, with its size (composites flatten on construction)."""

    kind: str  # "seq" | "fb" | "cond" | "act"
    items: tuple
    size: int


def _cond(lit: Literal) -> _N:
    return _N("cond", (lit,), 1)


def _act(action: int) -> _N:
    return _N("act", (action,), 1)


def compose_node(kind: str, children: list[_N] | tuple[_N, ...]) -> _N:
    """A ``kind`` node of ``children``, flattening children of the same kind (one child: itself)."""
    flat: list[_N] = []
    for child in children:
        flat.extend(child.items if child.kind == kind else (child,))
    if len(flat) == 1:
        return flat[0]
    return _N(kind, tuple(flat), 1 + sum(c.size for c in flat))


def _or_node(terms: frozenset[Term], memo: dict) -> _N:
    """The smallest algebraic factoring of an OR of non-empty conjunctions (no actions)."""
    if terms in memo:
        return memo[terms]
    ordered = sorted(terms)
    best = compose_node("fb", [compose_node("seq", [_cond(x) for x in t]) for t in ordered])
    counts: dict[Literal, int] = {}
    for t in ordered:
        for lit in t:
            counts[lit] = counts.get(lit, 0) + 1
    shared = sorted((x for x, c in counts.items() if c >= 2), key=lambda x: (-counts[x], x))
    for lit in shared[: OR_BRANCHING if len(terms) <= OR_BRANCHING_TERMS else 1]:
        inner = frozenset(tuple(x for x in t if x != lit) for t in terms if lit in t)
        others = frozenset(t for t in terms if lit not in t)
        head = _cond(lit) if () in inner else compose_node("seq", [_cond(lit),
                                                                   _or_node(inner, memo)])
        node = compose_node("fb", [head, _or_node(others, memo)]) if others else head
        if node.size < best.size:
            best = node
    memo[terms] = best
    return best


def guarded_action(terms: list[Term], action: int, memo: dict) -> _N:
    """``Sequence(OR of terms, action)``, the OR factored; just the action if a term is empty."""
    if any(not t for t in terms):
        return _act(action)
    return compose_node("seq", [_or_node(frozenset(terms), memo), _act(action)])


class Factorer:
    """Flat decision list -> the smallest nested BT an interval dynamic programme finds.

    The blocks of consecutive entries it considers: one entry (``Sequence(term..., action)``);
    a run of one action (``Sequence(OR of the terms, action)``, the OR factored algebraically);
    a run sharing a literal ``c`` (``Sequence(c, Fallback(the run without c))``, recursively).
    Every rewriting keeps the list's decisions on every state. Results are memoised, so one
    instance serves a whole search.
    """

    def __init__(self, deadline: float | None = None) -> None:
        self.deadline = deadline  # time.monotonic() past which _solve raises SearchTimeout
        self.memo: dict[tuple[Entry, ...], tuple[_N, ...]] = {}
        self.or_memo: dict = {}
        self.guard_memo: dict = {}

    def __call__(self, entries: list[Entry]) -> _N:
        return compose_node("fb", self._solve(tuple(entries)))

    def size(self, entries: list[Entry]) -> int:
        return self(entries).size

    def _guard(self, terms: tuple[Term, ...], action: int) -> _N:
        key = (terms, action)
        if key not in self.guard_memo:
            self.guard_memo[key] = guarded_action(list(terms), action, self.or_memo)
        return self.guard_memo[key]

    def _solve(self, es: tuple[Entry, ...]) -> tuple[_N, ...]:
        if es in self.memo:
            return self.memo[es]
        if self.deadline is not None and time.monotonic() > self.deadline:
            raise SearchTimeout
        n = len(es)
        best: list[tuple[int, tuple[_N, ...]]] = [(0, ())] * (n + 1)
        for i in range(n - 1, -1, -1):
            node = self._guard((es[i][0],), es[i][1])
            options = [(node.size + best[i + 1][0], (node, *best[i + 1][1]))]
            common = set(es[i][0])
            same = True
            for j in range(i + 1, n):
                common &= set(es[j][0])
                same = same and es[j][1] == es[i][1]
                if not common and not same:
                    break
                rest = best[j + 1]
                if same:
                    node = self._guard(tuple(t for t, _ in es[i:j + 1]), es[i][1])
                    options.append((node.size + rest[0], (node, *rest[1])))
                for lit in sorted(common):
                    inner = self._solve(tuple((tuple(x for x in t if x != lit), a)
                                              for t, a in es[i:j + 1]))
                    node = compose_node("seq", [_cond(lit), compose_node("fb", inner)])
                    options.append((node.size + rest[0], (node, *rest[1])))
            best[i] = min(options, key=lambda o: o[0])
        self.memo[es] = best[0][1]
        return best[0][1]


def factor(entries: list[Entry]) -> _N:
    """The smallest nested BT (the root's Fallback) :class:`Factorer` finds for a flat list."""
    return Factorer()(entries)


def _to_bt_node(node: _N) -> Node:
    if node.kind == "cond":
        lit = node.items[0]
        return Condition(lit.feature, lit.op, lit.threshold)
    if node.kind == "act":
        return Action(node.items[0])
    children = tuple(_to_bt_node(c) for c in node.items)
    return Sequence(children) if node.kind == "seq" else Fallback(children)


def root_selector(node: _N) -> Node:
    """A root Selector (a one-action BT is ``Selector(action)``, as Imitation-BT's)."""
    if node.kind == "fb":
        return Selector(tuple(_to_bt_node(c) for c in node.items))
    return Selector((_to_bt_node(node),))


__all__ = ["Factorer", "factor"]
