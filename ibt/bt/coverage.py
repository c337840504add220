"""Reachability: a proof that every state reaches an action of a Behavior Tree, or a state that
does not (what :meth:`ibt.bt.model.BehaviorTree.validate` reports).

Regions are unions of boxes over the features; the acting region of the root is
under-approximated and its complement searched for an uncovered box.

**Relational conditions**. Each distinct linear form of the BT is one more
coordinate of the boxes, its *derived value* (column ``n_features + k``), treated as a free
variable: a box over observed features and derived values holds every state whose features and
computed forms lie in it. A proof that the boxes cover every point of this larger space covers
every state (each state is one such point), so the proof stays sound; it is also complete for
every BT synthesised from a relational tree, since those are exact on the larger space (the
synthesisers read the derived columns as features). A derived value is a double compared with
the condition's threshold as it is (no float32 snapping). A gap the search finds there may hold
no real state (its forms contradict each other or its features): the gap is then searched for a
state with a linear program (:mod:`ibt.bt.polytope`); the state found, or the gap's best guess,
is returned, and :meth:`~ibt.bt.model.BehaviorTree.validate` refuses the BT either way, saying
that the proof failed where no state reaching no action was found. So a hand-written BT whose
guards cover the plane only geometrically (``x - y <= 0`` beside ``y - x < 0``) is refused:
end its root with a default action.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ibt.bt.linear import Form
from ibt.bt.model import (
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Node,
    Sequence,
)

# Does every state reach an action? A sound proof over boxes: a box maps features to intervals
# (lo, hi] (unlisted features are free); a union of boxes is a list. Thresholds are snapped to
# the largest float32 not above them, which decides every float32 observation alike, so a box
# holds an observation iff lo < hi on every feature.
Box = dict[int, tuple[float, float]]
MAX_BOXES = 4096  # larger unions are dropped from the (under-approximating) acting region
MAX_REGIONS = 200_000  # regions the cover search may visit before it gives up


@dataclass(frozen=True)
class _Facts:
    """What holds on every state: a tick acts; success implies it acted; it always succeeds;
    it always fails; the subtree contains an action."""

    acts: bool
    guarded: bool
    succeeds: bool
    fails: bool
    has_action: bool


def _facts(node: Node, memo: dict[int, _Facts]) -> _Facts:
    if id(node) in memo:
        return memo[id(node)]
    if isinstance(node, Action):
        out = _Facts(True, True, True, False, True)
    elif isinstance(node, Condition):
        out = _Facts(False, False, False, False, False)
    elif isinstance(node, Inverter):
        c = _facts(node.child, memo)
        out = _Facts(c.acts, c.acts or c.succeeds, c.fails, c.succeeds, c.has_action)
    else:
        kids = [_facts(child, memo) for child in node.children]
        sequence = isinstance(node, Sequence)
        acts = False
        for k in kids:  # a sequence goes on after a success, a fallback after a failure
            if k.acts:
                acts = True
                break
            if not (k.succeeds if sequence else k.guarded):
                break
        if sequence:
            succeeds, fails = all(k.succeeds for k in kids), any(k.fails for k in kids)
            guarded = acts or fails or any(k.guarded for k in kids)
        else:
            succeeds, fails = any(k.succeeds for k in kids), all(k.fails for k in kids)
            guarded = acts or fails or all(k.guarded for k in kids)
        out = _Facts(acts, guarded, succeeds, fails, any(k.has_action for k in kids))
    memo[id(node)] = out
    return out


def _snap(threshold: float) -> float:
    value = np.float32(threshold)
    if float(value) > threshold:
        value = np.nextafter(value, np.float32(-np.inf))
    return float(value)


def _meet(a: Box, b: Box) -> Box | None:
    out = dict(a)
    for feature, (lo, hi) in b.items():
        if feature in out:
            lo, hi = max(lo, out[feature][0]), min(hi, out[feature][1])
        if lo >= hi:
            return None
        out[feature] = (lo, hi)
    return out


def _and(a: list[Box] | None, b: list[Box] | None) -> list[Box] | None:
    if a is None or b is None:
        return None
    out = [m for x in a for y in b if (m := _meet(x, y)) is not None]
    return out if len(out) <= MAX_BOXES else None


Columns = dict[Form, int]  # each linear form of a BT -> its derived coordinate


def _truth(node: Node, negate: bool = False, columns: Columns | None = None
           ) -> list[Box] | None:
    """Where an action-free subtree succeeds (fails, if ``negate``); None if too large."""
    if isinstance(node, Condition) and node.form is not None:
        assert columns is not None
        below = (node.op == "<=") != negate
        key, t = columns[node.form], node.threshold  # a double compared as it is
        return [{key: (-math.inf, t) if below else (t, math.inf)}]
    if isinstance(node, Condition):
        t = _snap(node.threshold)
        below = (node.op == "<=") != negate
        return [{node.feature: (-math.inf, t) if below else (t, math.inf)}]
    if isinstance(node, Inverter):
        return _truth(node.child, not negate, columns)
    parts = [_truth(child, negate, columns) for child in getattr(node, "children", ())]
    if isinstance(node, Sequence) != negate:  # a conjunction
        out: list[Box] | None = [{}]
        for part in parts:
            out = _and(out, part)
        return out
    if any(part is None for part in parts):
        return None
    union = [box for part in parts for box in part or ()]
    return union if len(union) <= MAX_BOXES else None


def _acting(node: Node, memo: dict[int, _Facts], columns: Columns | None = None) -> list[Box]:
    """States on which a tick of ``node`` surely reaches an action (an under-approximation)."""
    facts = _facts(node, memo)
    if facts.acts:
        return [{}]
    if isinstance(node, Inverter):
        return _acting(node.child, memo, columns)
    if not isinstance(node, Fallback | Sequence):
        return []
    sequence = isinstance(node, Sequence)
    out: list[Box] = []
    reach: list[Box] | None = [{}]  # states that reach this child or have already acted
    for child in node.children:
        acting = _acting(child, memo, columns)
        out += [m for r in reach or () for b in acting if (m := _meet(r, b)) is not None]
        kid = _facts(child, memo)
        if not kid.has_action:
            reach = _and(reach, _truth(child, negate=not sequence, columns=columns))
        elif not (kid.succeeds if sequence else kid.guarded):
            break
        if not reach or len(out) > MAX_BOXES:
            break
    return out


def _contains(box: Box, region: Box) -> bool:
    full = (-math.inf, math.inf)
    return all(lo <= region.get(f, full)[0] and region.get(f, full)[1] <= hi
               for f, (lo, hi) in box.items())


def _first_cut(region: Box, live: list[Box]) -> tuple[int, float]:
    """A bound of the first box that cuts the region (the original search order)."""
    full = (-math.inf, math.inf)
    for feature, (lo, hi) in live[0].items():
        rlo, rhi = region.get(feature, full)
        cut = lo if rlo < lo < rhi else hi if rlo < hi < rhi else None
        if cut is not None:
            return feature, cut
    raise AssertionError("a live box that does not contain the region cuts it")


def _shared_cut(region: Box, live: list[Box]) -> tuple[int, float]:
    """The bound that cuts the region in the most live boxes (ties: the smallest feature,
    then cut): it follows a source tree's splits from its root, so the search stays small on
    many features (the derived values of a relational BT)."""
    full = (-math.inf, math.inf)
    counts: dict[tuple[int, float], int] = {}
    for box in live:
        for feature, (lo, hi) in box.items():
            rlo, rhi = region.get(feature, full)
            for cut in (lo, hi):
                if rlo < cut < rhi:
                    counts[(feature, cut)] = counts.get((feature, cut), 0) + 1
    return min(counts, key=lambda key: (-counts[key], key))


def _uncovered(boxes: list[Box], relational: bool = False) -> Box | None:
    """A region no box touches, or None when the boxes cover every state.

    The search splits regions on the first live box's bounds; if that gives up
    (:data:`MAX_REGIONS`), it starts again splitting on the bound most live boxes share
    (:func:`_shared_cut`). Both are sound; the retry only changes BTs the first search could
    not decide, so every axis-aligned BT it proved or refused before is proved or refused
    alike. A relational BT (many derived coordinates) starts with the shared bound: on a
    100-leaf LunarLander tree's RE:BT-Espresso BT it decides in 0.06 s where the first order
    gives up after 200,000 regions."""
    first, second = (_shared_cut, _first_cut) if relational else (_first_cut, _shared_cut)
    try:
        return _search(boxes, first)
    except ValueError:
        return _search(boxes, second)


def _search(boxes: list[Box], choose: Callable[[Box, list[Box]], tuple[int, float]]
            ) -> Box | None:
    full = (-math.inf, math.inf)
    stack: list[tuple[Box, list[Box]]] = [({}, boxes)]
    visited = 0
    while stack:
        region, candidates = stack.pop()
        visited += 1
        if visited > MAX_REGIONS:
            raise ValueError(f"could not prove within {MAX_REGIONS} regions that every state "
                             "reaches an action; end the root Selector with an unguarded "
                             "default action")
        live = [b for b in candidates if _meet(region, b) is not None]
        if not live:
            return region
        if any(_contains(b, region) for b in live):
            continue
        feature, cut = choose(region, live)  # split the region at a bound that cuts it
        rlo, rhi = region.get(feature, full)
        stack.append(({**region, feature: (cut, rhi)}, live))
        stack.append(({**region, feature: (rlo, cut)}, live))
    return None


def unreached_state(tree: BehaviorTree) -> np.ndarray | None:
    """A state on which ticking ``tree`` reaches no action, or None when every state (every
    float32 observation) provably reaches one. Raises ``ValueError`` if the search gives up."""
    memo: dict[int, _Facts] = {}
    if _facts(tree.root, memo).acts:
        return None
    forms = sorted({node.form for node in tree.nodes()
                    if isinstance(node, Condition) and node.form is not None},
                   key=lambda form: (len(form.terms), form.terms))
    columns = {form: tree.n_features + k for k, form in enumerate(forms)}
    region = _uncovered(_acting(tree.root, memo, columns), relational=bool(columns))
    if region is None:
        return None
    if any(key >= tree.n_features for key in region):  # a gap with derived values
        from ibt.bt.polytope import region_state

        return region_state(tree.n_features, region, forms)
    state = np.zeros(tree.n_features, dtype=np.float32)
    for feature, (lo, hi) in region.items():
        state[feature] = hi if math.isfinite(hi) else (
            np.nextafter(np.float32(lo), np.float32(np.inf)) if math.isfinite(lo) else 0.0)
    return state
