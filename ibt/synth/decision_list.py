"""Decision-list synthesis: smaller exact BTs from decision trees (beyond the paper).

A root Selector is a *decision list*: a state reaches the k-th child only when every earlier child
failed. Imitation-BT (:mod:`ibt.synth.imitation`) ignores this and minimises each action's rule set
as
if no other rule existed. Method ``"decision-list"`` uses it:

1. **Rule sets in Selector order** (:meth:`CandidateSearch.espresso_list`): for an action order (the
   last action is the unguarded default), each action's cover is minimised by Espresso with the
   earlier rules' regions as extra don't-cares, besides the threshold-implication don't-cares
   of :mod:`ibt.synth.logic`. Order and default are searched together: every order up to
   ``EXHAUSTIVE_ACTIONS`` actions (the paper's order first), a beam search over order prefixes
   beyond (PackageDelivery has 8 actions).
2. **Tree-shaped candidates**: a split ``if c then L else R`` is ``Fallback(Sequence(c, L), R)``,
   one condition per split (:meth:`CandidateSearch.tree_shaped`). A dynamic programme over the
   tree (:meth:`CandidateSearch.programme`) picks for every subtree the smaller of "split here,
   either branch guarded, each side solved the same way" and "one decision list for the subtree"
   (its don't-cares include everything outside the subtree), so a shared tree prefix is tested once
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

Steps 1 and 2 live in :mod:`ibt.synth.decision_list_search`, step 3 in
:mod:`ibt.synth.decision_list_exact`, step 4 in :mod:`ibt.synth.decision_list_factoring`; this
module runs them, compares the candidates and writes the winner.

Candidates (tree-shaped, the paper's order, the best order, the programme) are compared by BT
nodes, then condition nodes; Imitation-BT's own BT is one of them, so the result is never
larger. The winner is verified against its tree like every synthesised BT
(:func:`ibt.synth.imitation.verify`).

**Determinism.** Every search step runs in a fixed order and the search is bounded in Espresso
*work units* (``max_work``, see :class:`EspressoBudget`), never in seconds: a tree always gives the
same BT. ``time_limit`` (seconds) is only a safety net: past it the search stops, warns and
returns the best candidate found so far (still verified). The net covers every step after the
search too: simplifying and factoring a candidate check the same deadline, and past it a
candidate is written as its flat decision list (exact as it is, one Sequence per entry), the
remaining candidates and Imitation-BT's are skipped; so a 1,000-leaf tree stops near its limit
instead of simplifying for minutes. The committed trees use at most a third of the work budget
and take a few seconds (the test on the largest one asserts both): the net never bites there.
"""

from __future__ import annotations

import time
import warnings

import pandas as pd
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import BehaviorTree, Node, iterate
from ibt.synth.decision_list_exact import Entry, SearchTimeout, decides_like, simplify, term_box
from ibt.synth.decision_list_factoring import compose_node, guarded_action, root_selector
from ibt.synth.decision_list_search import (
    CandidateSearch,
    EspressoBudget,
    Split,
    condition_count,
    tree_view,
    view_paths,
)
from ibt.synth.imitation import RuleSet, Synthesis, imitation_bt, verify
from ibt.synth.rules import Term
from ibt.tasks.catalogue import Task

METHOD = "decision-list"
VERSION = 1  # part of the synthesis cache key of this method: bump when its search changes
MAX_WORK = 1_500_000  # Espresso work units (see EspressoBudget) of one synthesis
TIME_LIMIT = 60.0  # seconds; a safety net, see the module docstring
PROGRAMME_KEEP = (1,)  # lists kept per region by the tree programme (keeping 3 gained < 1 %)


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
    view = tree_view(tree)
    tested = [lit.feature for term, _ in view_paths(view) for lit in term]
    if tested and max(tested) >= task.n_features:
        raise ValueError(f"the tree tests feature {max(tested)}, but task {task.name} has "
                         f"{task.n_features} features; synthesise with the task it was fitted on")
    search = CandidateSearch(view, EspressoBudget(max_work, time_limit))
    leaves = [(term_box(term, task.n_features), a) for term, a in search.paths]
    lists: list[tuple[str, list[Entry]]] = [("tree-shaped", search.tree_shaped())]
    stopped = False
    try:
        if isinstance(view, Split):
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
            root = root_selector(search.factorer(entries))
        except SearchTimeout:  # the safety net: this candidate as its flat (exact) list
            stopped = True
            root = root_selector(compose_node(
                "fb", [guarded_action([t], a, {}) for t, a in entries]))
        key = (_size(root), condition_count(entries))
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
