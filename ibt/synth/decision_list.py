"""Decision-list synthesis: smaller exact BTs from decision trees (beyond the paper).

A root Selector is a *decision list*: a state reaches the k-th child only when every earlier child
failed. Imitation-BT (:mod:`ibt.synth.imitation`) ignores this and minimises each action's rule set
as
if no other rule existed. Method ``"decision-list"`` uses it:

1. **Rule sets in Selector order** (:meth:`_Search.espresso_list`): for an action order (the
   last action is the unguarded default), each action's cover is minimised by Espresso with the
   earlier rules' regions as extra don't-cares, besides the threshold-implication don't-cares
   of :mod:`ibt.synth.logic`. Order and default are searched together: every order up to
   ``EXHAUSTIVE_ACTIONS`` actions (the paper's order first), a beam search over order prefixes
   beyond (PackageDelivery has 8 actions).
2. **Tree-shaped candidates**: a split ``if c then L else R`` is ``Fallback(Sequence(c, L), R)``,
   one condition per split (:meth:`_Search.tree_shaped`). A dynamic programme over the tree
   (:meth:`_Search.programme`) picks for every subtree the smaller of "split here, either branch
   guarded, each side solved the same way" and "one decision list for the subtree" (its
   don't-cares include everything outside the subtree), so a shared tree prefix is tested once
   while the leaves below it merge into decision lists.
3. **Exact simplification** (:func:`simplify`): a candidate is a flat list of
   ``(term, action)`` entries; entries, then literals, are dropped one at a time, in a fixed
   order, while the list still decides as the tree on every real state. The check
   (:func:`decides_like`) is interval arithmetic on the tree's leaf boxes, not sampling.
4. **Factoring** (:class:`Factorer`, the algebraic factoring of logic synthesis): the flat list
   becomes the smallest nested BT an interval dynamic programme finds. Consecutive entries of
   one action share one Action (``Sequence(Fallback(terms...), action)``, the OR factored by
   shared literals, recursively), and consecutive entries sharing a literal test it once
   (``Sequence(c, Fallback(rest...))``).

Candidates (tree-shaped, the paper's order, the best order, the programme) are compared by BT
nodes, then condition nodes; Imitation-BT's own BT is one of them, so the result is never
larger. The winner is verified against its tree like every synthesised BT
(:func:`ibt.synth.imitation.verify`).

**Determinism.** Every search step runs in a fixed order and the search is bounded in Espresso
*work units* (``max_work``, see :class:`_Budget`), never in seconds: a tree always gives the
same BT. ``time_limit`` (seconds) is only a safety net: past it the search stops, warns and
returns the best candidate found so far (still verified). The net covers every step after the
search too: simplifying and factoring a candidate check the same deadline, and past it a
candidate is written as its flat decision list (exact as it is, one Sequence per entry), the
remaining candidates and Imitation-BT's are skipped; so a 1,000-leaf tree stops near its limit
instead of simplifying for minutes. The committed trees use at most a third of the work budget
and take a few seconds (the test on the largest one asserts both): the net never bites there.
"""

from __future__ import annotations

import itertools
import time
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import (
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Node,
    Selector,
    Sequence,
    iterate,
)
from ibt.synth.imitation import RuleSet, Synthesis, imitation_bt, minimised_rule_sets, verify
from ibt.synth.logic import Variables, minimise
from ibt.synth.rules import Literal, Term
from ibt.tasks.catalogue import Task

METHOD = "decision-list"
VERSION = 1  # part of the synthesis cache key of this method: bump when its search changes
EXHAUSTIVE_ACTIONS = 6  # every action order up to this many actions; a beam search beyond
BEAM_WIDTH = 6  # order prefixes kept per step (12 and 24 gave the same PackageDelivery BTs)
MAX_WORK = 1_500_000  # Espresso work units (see _Budget) of one synthesis
TIME_LIMIT = 60.0  # seconds; a safety net, see the module docstring
# Espresso calls up to this many work units run in this process (the largest of the committed
# trees take ~20 ms; 45,000-unit calls on 64-leaf trees ~0.5 s); larger ones in a child
# process with ibt.synth.logic's 30 s time limit (then the unminimised cover, still exact)
IN_PROCESS_WORK = 60_000
PROGRAMME_KEEP = (1,)  # lists kept per region by the tree programme (keeping 3 gained < 1 %)
# algebraic factoring of one action's OR: the OR_BRANCHING most shared literals are tried as
# divisors (recursively) for ORs of up to OR_BRANCHING_TERMS terms, the most shared one beyond
OR_BRANCHING = 3
OR_BRANCHING_TERMS = 12

Entry = tuple[Term, int]  # a decision-list entry: if term holds, decide action


class SearchTimeout(Exception):
    """The wall-clock safety net of the search was hit."""


# ----------------------------------------------------------------------------- the tree
@dataclass(frozen=True)
class _Leaf:
    action: int


@dataclass(frozen=True)
class _Split:
    literal: Literal  # the test sending a state left (``x <= t``)
    left: _Leaf | _Split
    right: _Leaf | _Split


_View = _Leaf | _Split


def _view(tree: DecisionTreeClassifier) -> _View:
    """The tree as nested splits, subtrees whose leaves all predict one action collapsed."""
    t = tree.tree_
    classes = np.asarray(tree.classes_)

    def build(node: int) -> _View:
        left, right = int(t.children_left[node]), int(t.children_right[node])
        if left == right:
            return _Leaf(int(classes[int(np.argmax(t.value[node][0]))]))
        lo, hi = build(left), build(right)
        if isinstance(lo, _Leaf) and lo == hi:
            return lo
        return _Split(Literal(int(t.feature[node]), float(t.threshold[node]), le=True), lo, hi)

    return build(0)


def _paths(view: _View, prefix: Term = ()) -> list[Entry]:
    """Every leaf of ``view`` as (path below the view's root, action), left before right."""
    if isinstance(view, _Leaf):
        return [(prefix, view.action)]
    return (_paths(view.left, (*prefix, view.literal))
            + _paths(view.right, (*prefix, view.literal.negated())))


def _actions(view: _View) -> tuple[int, ...]:
    return tuple(sorted({a for _, a in _paths(view)}))


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


def _box(term: Term, n_features: int) -> Box:
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


# --------------------------------------------------------------------- candidate lists
def _tighten(term: Term) -> Term:
    """Drop literals implied by another of the same term (``x <= 1`` beside ``x <= 0.5``)."""
    bounds = _term_bounds(term)
    out: list[Literal] = []
    for lit in term:
        lo, hi = bounds[lit.feature]
        keep = lit.threshold == hi if lit.le else lit.threshold == lo
        if keep and lit not in out:
            out.append(lit)
    return tuple(out)


class _Budget:
    """Counts Espresso work (the deterministic unit) and watches the wall-clock safety net.

    One Espresso call costs ``variables x (ON cubes + don't-care cubes)`` units, a proxy that
    tracks its run time (log-log correlation 0.94 over the calls of the committed trees).
    """

    def __init__(self, max_work: int, time_limit: float) -> None:
        self.max_work = max_work
        self.time_limit = time_limit
        self.deadline = time.monotonic() + time_limit
        self.work = 0

    def spend(self, units: int) -> bool:
        """Take ``units`` from the budget; False (and nothing taken) when they do not fit."""
        if time.monotonic() > self.deadline:
            raise SearchTimeout
        if self.work + units > self.max_work:
            return False
        self.work += units
        return True


def _flat_size(entries: list[Entry]) -> int:
    return sum(len(t) + 2 for t, _ in entries)


def _conditions(entries: list[Entry]) -> int:
    return sum(len(t) for t, _ in entries)


def _prefix(lit: Literal, entries: list[Entry]) -> list[Entry]:
    return [(_tighten((lit, *t)), a) for t, a in entries]


def _ranked(paths: list[Entry]) -> tuple[int, ...]:
    """Actions by increasing literal count of their paths (the paper's order: the most
    complex last), so the order search meets the paper's order first."""
    k: dict[int, int] = {}
    for term, action in paths:
        k[action] = k.get(action, 0) + len(term)
    return tuple(sorted(k, key=lambda a: (k[a], a)))


class _Search:
    """The candidate lists of one tree: Espresso decision lists and the tree programme."""

    def __init__(self, view: _View, budget: _Budget) -> None:
        self.view = view
        self.paths = _paths(view)
        self.variables = Variables(t for t, _ in self.paths)
        self.budget = budget
        self.factorer = Factorer(budget.deadline)
        self.espresso: dict[tuple[Term, tuple[int, ...]], list[Term]] = {}
        self.memo: dict[tuple[int, int, Term], list[list[Entry]]] = {}
        self.local: dict[Term, tuple[Variables, int]] = {}

    def key(self, entries: list[Entry]) -> tuple[int, int]:
        """What the search minimises: BT nodes, then condition nodes."""
        return self.factorer.size(entries), _conditions(entries)

    def espresso_list(self, paths: list[Entry], context: Term, order: tuple[int, ...]
                      ) -> list[Entry] | None:
        """The decision list of ``paths`` in action ``order`` (the last is the default).

        Each action's cover is minimised with the earlier actions' minimised terms and the
        states outside ``context`` (the subtree's region) as don't-cares; ``None`` when the
        work budget is spent.
        """
        outside = [(lit.negated(),) for lit in context]
        entries: list[Entry] = []
        earlier: list[Term] = []
        for k, action in enumerate(order[:-1]):
            key = (context, order[: k + 1])
            if key not in self.espresso:
                terms = [t for t, a in paths if a == action]
                variables, n_implied = self._local(context)
                units = len(variables) * (len(terms) + n_implied + len(outside) + len(earlier))
                if not self.budget.spend(units):
                    return None
                self.espresso[key] = minimise(terms, variables, dont_cares=True,
                                              extra_dont_cares=outside + earlier,
                                              in_process_limit=IN_PROCESS_WORK)
            entries += [(_tighten(term), action) for term in self.espresso[key]]
            earlier = earlier + self.espresso[key]
        entries.append(((), order[-1]))
        return entries

    def _local(self, context: Term) -> tuple[Variables, int]:
        """The variables of a region (its paths' and its context's tests) and how many
        implication don't-cares they have."""
        if context not in self.local:  # a context (root-to-subtree path) names its region
            paths = _paths(self._subtree(context))
            variables = Variables([*(t for t, _ in paths), context])
            self.local[context] = (variables, len(variables.implication_dont_cares()))
        return self.local[context]

    def _subtree(self, context: Term) -> _View:
        view = self.view
        for lit in context:
            assert isinstance(view, _Split)
            view = view.left if lit.le else view.right
        return view

    def best_list(self, paths: list[Entry], context: Term) -> list[Entry] | None:
        """The smallest decision list over action orders: every order up to
        ``EXHAUSTIVE_ACTIONS`` actions, a beam search over order prefixes beyond."""
        actions = _ranked(paths)
        if len(actions) == 1:
            return [((), actions[0])]
        if len(actions) <= EXHAUSTIVE_ACTIONS:
            orders: list[tuple[int, ...]] = list(itertools.permutations(actions))
        else:
            orders = self._beam_orders(paths, context, actions)
        best: tuple[tuple[int, int], list[Entry]] | None = None
        for order in orders:
            entries = self.espresso_list(paths, context, order)
            if entries is None:
                break
            key = self.key(entries)
            if best is None or key < best[0]:
                best = (key, entries)
        return None if best is None else best[1]

    def _beam_orders(self, paths: list[Entry], context: Term, actions: tuple[int, ...]
                     ) -> list[tuple[int, ...]]:
        """Complete orders from a beam over prefixes scored by their rules' flat size."""
        beam: list[tuple[int, ...]] = [()]
        for _ in range(len(actions) - 2):
            scored = []
            for prefix in beam:
                for a in actions:
                    if a in prefix:
                        continue
                    order = (*prefix, a)
                    rest = tuple(x for x in actions if x not in order)
                    entries = self.espresso_list(paths, context, (*order, rest[0]))
                    if entries is not None:
                        scored.append((_flat_size(entries[:-1]), order))
            if not scored:
                break
            beam = [order for _, order in sorted(scored)[:BEAM_WIDTH]]
        orders = []
        for prefix in beam:
            left = [x for x in actions if x not in prefix]
            orders += [(*prefix, *p) for p in itertools.permutations(left)]
        return orders

    def tree_shaped(self, view: _View | None = None) -> list[Entry]:
        """``if c then L else R`` as ``Fallback(Sequence(c, L), R)``: one condition a split."""
        view = self.view if view is None else view
        if isinstance(view, _Leaf):
            return [((), view.action)]
        return _prefix(view.literal, self.tree_shaped(view.left)) + self.tree_shaped(view.right)

    def programme(self, keep: int = 1, view: _View | None = None, context: Term = ()
                  ) -> list[list[Entry]]:
        """The ``keep`` smallest lists for ``view``'s region: split at its root (either branch
        guarded, each side's ``keep`` best lists combined), or one decision list for the
        region. The key is (view, context): a context (root-to-subtree path) names a region."""
        view = self.view if view is None else view
        key = (keep, id(view), context)
        if key in self.memo:
            return self.memo[key]
        if isinstance(view, _Leaf):
            self.memo[key] = [[((), view.action)]]
            return self.memo[key]
        lit = view.literal
        lefts = self.programme(keep, view.left, (*context, lit))
        rights = self.programme(keep, view.right, (*context, lit.negated()))
        options = []
        for left, right in itertools.product(lefts, rights):
            options += [_prefix(lit, left) + right, _prefix(lit.negated(), right) + left]
        dl = self.best_list(_paths(view), context)
        if dl is not None:
            options.append(dl)
        ranked: list[list[Entry]] = []
        for option in sorted(options, key=self.key):  # stable: ties keep the option order
            if option not in ranked:
                ranked.append(option)
        self.memo[key] = ranked[:keep]
        return self.memo[key]

    def paper_order(self, tree: DecisionTreeClassifier) -> list[Entry]:
        """The decision list in Imitation-BT's order (increasing k, the largest k last)."""
        sets = minimised_rule_sets(tree)
        order = tuple(rs.action for rs in sets)
        return self.espresso_list(self.paths, (), order) or []


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


# ---------------------------------------------------------------------------- factoring
class _N(NamedTuple):
    """A BT node during the search, with its size (composites flatten on construction)."""

    kind: str  # "seq" | "fb" | "cond" | "act"
    items: tuple
    size: int


def _cond(lit: Literal) -> _N:
    return _N("cond", (lit,), 1)


def _act(action: int) -> _N:
    return _N("act", (action,), 1)


def _compose(kind: str, children: list[_N] | tuple[_N, ...]) -> _N:
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
    best = _compose("fb", [_compose("seq", [_cond(x) for x in t]) for t in ordered])
    counts: dict[Literal, int] = {}
    for t in ordered:
        for lit in t:
            counts[lit] = counts.get(lit, 0) + 1
    shared = sorted((x for x, c in counts.items() if c >= 2), key=lambda x: (-counts[x], x))
    for lit in shared[: OR_BRANCHING if len(terms) <= OR_BRANCHING_TERMS else 1]:
        inner = frozenset(tuple(x for x in t if x != lit) for t in terms if lit in t)
        others = frozenset(t for t in terms if lit not in t)
        head = _cond(lit) if () in inner else _compose("seq", [_cond(lit),
                                                              _or_node(inner, memo)])
        node = _compose("fb", [head, _or_node(others, memo)]) if others else head
        if node.size < best.size:
            best = node
    memo[terms] = best
    return best


def _guarded(terms: list[Term], action: int, memo: dict) -> _N:
    if any(not t for t in terms):
        return _act(action)
    return _compose("seq", [_or_node(frozenset(terms), memo), _act(action)])


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
        return _compose("fb", self._solve(tuple(entries)))

    def size(self, entries: list[Entry]) -> int:
        return self(entries).size

    def _guard(self, terms: tuple[Term, ...], action: int) -> _N:
        key = (terms, action)
        if key not in self.guard_memo:
            self.guard_memo[key] = _guarded(list(terms), action, self.or_memo)
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
                    node = _compose("seq", [_cond(lit), _compose("fb", inner)])
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


def _root(node: _N) -> Node:
    """A root Selector (a one-action BT is ``Selector(action)``, as Imitation-BT's)."""
    if node.kind == "fb":
        return Selector(tuple(_to_bt_node(c) for c in node.items))
    return Selector((_to_bt_node(node),))


# ---------------------------------------------------------------------------- the method
def decision_list_bt(tree: DecisionTreeClassifier, task: Task, *, time_limit: float = TIME_LIMIT,
                     max_work: int = MAX_WORK, check: bool = True,
                     rng_seed: int = 0) -> Synthesis:
    """The smallest exact BT the decision-list search finds for ``tree`` (method
    ``"decision-list"``); never larger than the paper's Imitation-BT of the same tree.

    Works on any fitted ``DecisionTreeClassifier`` whose class labels are action indices of
    ``task`` (any subset, in any order; a single leaf gives ``Selector(action)``).
    Candidates (named in ``result.search["candidates"]`` with their BT nodes): the
    tree-shaped list, the decision list in Imitation-BT's action order, the best decision list
    over action orders, the tree programme (module docstring) and Imitation-BT's BT itself; the
    one with the fewest nodes, then conditions, wins (earlier candidates win ties).
    Deterministic for a given tree: the search is bounded by ``max_work`` Espresso work units
    (``result.search["work"]`` says how many it used); ``time_limit`` seconds is a safety net
    that stops the search early with a warning. Raises
    :class:`ibt.synth.imitation.NotEquivalentError` when ``check`` and the BT disagrees with
    ``tree`` (it should not: every candidate is proven exact on the leaf boxes first). A
    relational tree goes through :func:`ibt.synth.relational.synthesise`.
    """
    from ibt.synth import relational

    if relational.is_relational(tree):
        return relational.synthesise(decision_list_bt, tree, task, time_limit=time_limit,
                                     max_work=max_work, check=check, rng_seed=rng_seed)
    view = _view(tree)
    tested = [lit.feature for term, _ in _paths(view) for lit in term]
    if tested and max(tested) >= task.n_features:
        raise ValueError(f"the tree tests feature {max(tested)}, but task {task.name} has "
                         f"{task.n_features} features; synthesise with the task it was fitted on")
    search = _Search(view, _Budget(max_work, time_limit))
    leaves = [(_box(term, task.n_features), a) for term, a in search.paths]
    lists: list[tuple[str, list[Entry]]] = [("tree-shaped", search.tree_shaped())]
    stopped = False
    try:
        if isinstance(view, _Split):
            lists.append(("paper order", search.paper_order(tree)))
            best_order = search.best_list(search.paths, ())
            if best_order is not None:
                lists.append(("best order", best_order))
            for keep in PROGRAMME_KEEP:
                lists += [("tree programme", entries) for entries in search.programme(keep)]
    except SearchTimeout:
        stopped = True
    sizes: dict[str, int] = {}
    best: tuple[tuple[int, int], str, Node, list[Entry] | None] | None = None
    deadline = search.budget.deadline
    for name, entries in lists:
        if not entries or (best is not None and time.monotonic() > deadline):
            continue
        try:
            entries = simplify(entries, leaves, deadline)
            if not decides_like(entries, leaves):  # simplify keeps exactness; never taken
                continue
            root = _root(search.factorer(entries))
        except SearchTimeout:  # the safety net: this candidate as its flat (exact) list
            stopped = True
            root = _root(_compose("fb", [_guarded([t], a, {}) for t, a in entries]))
        key = (_size(root), _conditions(entries))
        sizes[name] = min(sizes.get(name, key[0]), key[0])
        if best is None or key < best[0]:
            best = (key, name, root, entries)
    paper = None
    if time.monotonic() <= deadline:  # past the safety net, Imitation-BT's is not computed
        paper = imitation_bt(tree, task, check=False)
        paper_key = (paper.bt.node_count, paper.bt.node_types()["condition"])
        sizes["imitation-bt"] = paper_key[0]
        if best is None or paper_key < best[0]:
            best = (paper_key, "imitation-bt", paper.bt.root, None)
    else:
        stopped = True
    assert best is not None  # the tree-shaped list is never empty
    if stopped:
        warnings.warn(f"decision-list search stopped at its {time_limit:g} s safety net; "
                      "returning the best candidate found so far", stacklevel=2)
    _, winner, root, chosen = best
    if chosen is None:
        assert paper is not None
        rule_sets, default = paper.rule_sets, paper.default_action
    else:
        rule_sets, default = _rule_sets(chosen), chosen[-1][1]
    bt = BehaviorTree(root, task.feature_names, task.action_names, task.value_labels)
    info = {"winner": winner, "candidates": sizes, "work": search.budget.work,
            "max_work": max_work, "stopped_by_time_limit": stopped}
    result = Synthesis(bt, METHOD, default, "search", rule_sets, search=info)
    if check:
        verify(bt, tree, task, seed=rng_seed)
    return result


def _size(node: Node) -> int:
    return sum(1 for _ in iterate(node))


def _rule_sets(entries: list[Entry]) -> tuple[RuleSet, ...]:
    """Each action's terms in list order (the default's last rule is the empty term)."""
    by_action: dict[int, list[Term]] = {}
    for term, action in entries:
        by_action.setdefault(action, []).append(term)
    return tuple(RuleSet(a, tuple(ts)) for a, ts in by_action.items())


def size_table(synthesis: pd.DataFrame) -> pd.DataFrame:
    """Per task and expert, means over seeds: the source tree's nodes and splits beside the
    BT nodes and condition nodes of Imitation-BT and the decision-list BT (same trees).

    ``synthesis`` is ``data/results/synthesis.csv``; ``tree_splits`` is derived from
    ``tree_nodes`` (a binary tree has ``2 * splits + 1`` nodes) where the column is absent.
    """
    frame = synthesis[synthesis.method.isin(["imitation-bt", METHOD])].copy()
    if "tree_splits" not in frame or frame["tree_splits"].isna().any():
        frame["tree_splits"] = (frame["tree_nodes"] - 1) // 2
    wide = frame.pivot_table(index=["task", "expert", "seed"], columns="method",
                             values=["nodes", "conditions"], aggfunc="first")
    trees = frame.groupby(["task", "expert", "seed"])[["tree_nodes", "tree_splits"]].first()
    per_seed = pd.DataFrame({
        "tree nodes": trees["tree_nodes"], "tree splits": trees["tree_splits"],
        "Imitation-BT nodes": wide[("nodes", "imitation-bt")],
        "Imitation-BT conditions": wide[("conditions", "imitation-bt")],
        "decision-list nodes": wide[("nodes", METHOD)],
        "decision-list conditions": wide[("conditions", METHOD)]}).dropna()
    table = per_seed.groupby(["task", "expert"]).mean()
    table.insert(0, "seeds", per_seed.groupby(["task", "expert"]).size())
    table = table.reset_index()
    first = {c: {v: i for i, v in enumerate(dict.fromkeys(synthesis[c]))}
             for c in ("task", "expert")}
    table = table.sort_values(["task", "expert"], key=lambda col: col.map(first[col.name]),
                              kind="stable").reset_index(drop=True)  # the results' order
    table["conditions / splits"] = (table["decision-list conditions"]
                                    / table["tree splits"].where(table["tree splits"] > 0))
    table["nodes / Imitation-BT"] = (table["decision-list nodes"]
                                     / table["Imitation-BT nodes"])
    return table.round(2)
