"""The decision-list synthesis's candidate lists for one tree (:mod:`ibt.synth.decision_list`).

:class:`CandidateSearch` makes the candidates the synthesis compares, each a flat list of
``(term, action)`` entries:

* **rule sets in Selector order** (:meth:`CandidateSearch.espresso_list`): for an action order (the
  last action is the unguarded default), each action's cover is minimised by Espresso with the
  earlier rules' regions as extra don't-cares, besides the threshold-implication don't-cares
  of :mod:`ibt.synth.logic`. Order and default are searched together
  (:meth:`CandidateSearch.best_list`): every order up to ``EXHAUSTIVE_ACTIONS`` actions (the paper's
  order first), a beam search over order prefixes beyond (PackageDelivery has 8 actions).
* **tree-shaped** (:meth:`CandidateSearch.tree_shaped`): ``if c then L else R`` as
  ``Fallback(Sequence(c, L), R)``, one condition per split.
* **the tree programme** (:meth:`CandidateSearch.programme`): for every subtree the smaller
  of "split here, either branch guarded, each side solved the same way" and "one decision list
  for the subtree" (its don't-cares include everything outside the subtree).

The search is bounded in Espresso *work units* (:class:`EspressoBudget`), never in seconds, so a
tree always gives the same candidates; the wall-clock safety net raises
:class:`ibt.synth.decision_list_exact.SearchTimeout`.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.synth.decision_list_exact import Entry, SearchTimeout, tighten
from ibt.synth.decision_list_factoring import Factorer
from ibt.synth.imitation import minimised_rule_sets
from ibt.synth.logic import Variables, minimise
from ibt.synth.rules import Literal, Term

EXHAUSTIVE_ACTIONS = 6  # every action order up to this many actions; a beam search beyond
BEAM_WIDTH = 6  # order prefixes kept per step (12 and 24 gave the same PackageDelivery BTs)
# Espresso calls up to this many work units run in this process (the largest of the committed
# trees take ~20 ms; 45,000-unit calls on 64-leaf trees ~0.5 s); larger ones in a child
# process with ibt.synth.logic's 30 s time limit (then the unminimised cover, still exact)
IN_PROCESS_WORK = 60_000


@dataclass(frozen=True)
class Leaf:
    """A subtree whose every leaf predicts ``action``."""

    action: int


@dataclass(frozen=True)
class Split:
    """An inner node of the tree view: ``literal`` true goes ``left``, false ``right``."""

    literal: Literal  # the test sending a state left (``x <= t``)
    left: Leaf | Split
    right: Leaf | Split


_View = Leaf | Split


def tree_view(tree: DecisionTreeClassifier) -> _View:
    """The tree as nested splits, subtrees whose leaves all predict one action collapsed."""
    t = tree.tree_
    classes = np.asarray(tree.classes_)

    def build(node: int) -> _View:
        left, right = int(t.children_left[node]), int(t.children_right[node])
        if left == right:
            return Leaf(int(classes[int(np.argmax(t.value[node][0]))]))
        lo, hi = build(left), build(right)
        if isinstance(lo, Leaf) and lo == hi:
            return lo
        return Split(Literal(int(t.feature[node]), float(t.threshold[node]), le=True), lo, hi)

    return build(0)


def view_paths(view: _View, prefix: Term = ()) -> list[Entry]:
    """Every leaf of ``view`` as (path below the view's root, action), left before right."""
    if isinstance(view, Leaf):
        return [(prefix, view.action)]
    return (view_paths(view.left, (*prefix, view.literal))
            + view_paths(view.right, (*prefix, view.literal.negated())))


def _actions(view: _View) -> tuple[int, ...]:
    return tuple(sorted({a for _, a in view_paths(view)}))


class EspressoBudget:
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


def condition_count(entries: list[Entry]) -> int:
    """Condition literals of a flat decision list (the tie-break after BT nodes)."""
    return sum(len(t) for t, _ in entries)


def _prefix(lit: Literal, entries: list[Entry]) -> list[Entry]:
    return [(tighten((lit, *t)), a) for t, a in entries]


def _ranked(paths: list[Entry]) -> tuple[int, ...]:
    """Actions by increasing literal count of their paths (the paper's order: the most
    complex last), so the order search meets the paper's order first."""
    k: dict[int, int] = {}
    for term, action in paths:
        k[action] = k.get(action, 0) + len(term)
    return tuple(sorted(k, key=lambda a: (k[a], a)))


class CandidateSearch:
    """The candidate lists of one tree: Espresso decision lists and the tree programme."""

    def __init__(self, view: _View, budget: EspressoBudget) -> None:
        self.view = view
        self.paths = view_paths(view)
        self.variables = Variables(t for t, _ in self.paths)
        self.budget = budget
        self.factorer = Factorer(budget.deadline)
        self.espresso: dict[tuple[Term, tuple[int, ...]], list[Term]] = {}
        self.memo: dict[tuple[int, int, Term], list[list[Entry]]] = {}
        self.local: dict[Term, tuple[Variables, int]] = {}

    def key(self, entries: list[Entry]) -> tuple[int, int]:
        """What the search minimises: BT nodes, then condition nodes."""
        return self.factorer.size(entries), condition_count(entries)

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
            entries += [(tighten(term), action) for term in self.espresso[key]]
            earlier = earlier + self.espresso[key]
        entries.append(((), order[-1]))
        return entries

    def _local(self, context: Term) -> tuple[Variables, int]:
        """The variables of a region (its paths' and its context's tests) and how many
        implication don't-cares they have."""
        if context not in self.local:  # a context (root-to-subtree path) names its region
            paths = view_paths(self._subtree(context))
            variables = Variables([*(t for t, _ in paths), context])
            self.local[context] = (variables, len(variables.implication_dont_cares()))
        return self.local[context]

    def _subtree(self, context: Term) -> _View:
        view = self.view
        for lit in context:
            assert isinstance(view, Split)
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
        """Complete orders from a beam over prefixes scored by their rules' flat size: at most
        ``2 * BEAM_WIDTH`` (the last two actions both ways round each prefix kept), none where
        the work budget runs out first (not every order of the actions left: n! of them)."""
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
            if not scored:  # the work budget is spent: no order of these can be finished
                return []  # (the first completed order would fail where these did)
            beam = [order for _, order in sorted(scored)[:BEAM_WIDTH]]
        orders = []
        for prefix in beam:
            left = [x for x in actions if x not in prefix]
            orders += [(*prefix, *p) for p in itertools.permutations(left)]
        return orders

    def tree_shaped(self, view: _View | None = None) -> list[Entry]:
        """``if c then L else R`` as ``Fallback(Sequence(c, L), R)``: one condition a split."""
        view = self.view if view is None else view
        if isinstance(view, Leaf):
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
        if isinstance(view, Leaf):
            self.memo[key] = [[((), view.action)]]
            return self.memo[key]
        lit = view.literal
        lefts = self.programme(keep, view.left, (*context, lit))
        rights = self.programme(keep, view.right, (*context, lit.negated()))
        options = []
        for left, right in itertools.product(lefts, rights):
            options += [_prefix(lit, left) + right, _prefix(lit.negated(), right) + left]
        dl = self.best_list(view_paths(view), context)
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


__all__ = ["BEAM_WIDTH", "EXHAUSTIVE_ACTIONS", "IN_PROCESS_WORK"]
