"""The Behavior Tree model every other part of ``ibt`` consumes.

A synthesised policy is a tree of small frozen dataclasses:

* ``Selector`` / ``Fallback``: tick children in order, succeed on the first success
  (same semantics; ``Selector`` names the root, ``Fallback`` an inner choice between rules);
* ``Sequence``: tick children in order, fail on the first failure;
* ``Inverter``: flip its child's status;
* ``Condition``: succeeds when ``obs[feature] op threshold`` with ``op`` in ``<=`` / ``>``;
* ``Action``: succeeds and is the decision.

Policies here are reactive (the paper's scope): actions finish within one tick, so RUNNING never
occurs and a tick's decision is the first action ticked. Comparisons are made in double precision
on observations cast to float32 first, which is exactly how scikit-learn's trees decide; this is
what makes a synthesised BT decide *exactly* as its source tree.

The module offers three executors (``tick`` for one state with a trace, ``decide_batch`` for a
vectorised NumPy pass, and ``to_py_trees`` for the reference library), node counting, and the JSON
format of ``data/trees/``.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterator
from collections.abc import Sequence as Seq
from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

OPS = ("<=", ">")
NODE_TYPES = ("selector", "sequence", "fallback", "inverter", "condition", "action")
NO_DECISION = -1


@dataclass(frozen=True)
class Condition:
    """``obs[feature] <= threshold`` (op ``<=``) or ``obs[feature] > threshold`` (op ``>``)."""

    feature: int
    op: str
    threshold: float

    def __post_init__(self) -> None:
        if self.op not in OPS:
            raise ValueError(f"condition op must be one of {OPS}, got {self.op!r}")
        # normalised to plain int/float: NumPy scalars from scikit-learn compare equal anyway
        object.__setattr__(self, "feature", _index(self.feature, "a condition's feature"))
        object.__setattr__(self, "threshold", _finite(self.threshold))

    type = "condition"


@dataclass(frozen=True)
class Action:
    """A leaf that succeeds and makes ``action`` the tick's decision."""

    action: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "action", _index(self.action, "an action"))

    type = "action"


def _index(value: Any, what: str) -> int:
    """``value`` as a non-negative integer index, or a ``ValueError`` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{what} must be an integer index, got {value!r}")
    if value < 0:
        raise ValueError(f"{what} must be a non-negative index, got {value!r}")
    return int(value)


def _finite(value: Any) -> float:
    """``value`` as a finite float, or a ``ValueError``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"a condition's threshold must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"a condition's threshold must be finite, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Inverter:
    """Flip the status of ``child``."""

    child: Node
    type = "inverter"

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.child,)


@dataclass(frozen=True)
class Sequence:
    """Tick children in order; fail at the first failure, succeed when all succeed."""

    children: tuple[Node, ...] = field(default_factory=tuple)
    type = "sequence"


@dataclass(frozen=True)
class Fallback:
    """Tick children in order; succeed at the first success, fail when all fail."""

    children: tuple[Node, ...] = field(default_factory=tuple)
    type = "fallback"


@dataclass(frozen=True)
class Selector(Fallback):
    """A Fallback used as the root of a synthesised policy."""

    type = "selector"


Node = Union[Selector, Fallback, Sequence, Inverter, Condition, Action]  # noqa: UP007


@dataclass(frozen=True)
class BehaviorTree:
    """A BT with the names that make it readable and runnable on its own."""

    root: Node
    feature_names: tuple[str, ...]
    action_names: tuple[str, ...]
    # labels of categorical features' integer values 0..k-1 ({feature index: labels}); only
    # used to print conditions readably (``carrying == heavy``), never to decide
    value_labels: tuple[tuple[int, tuple[str, ...]], ...] = ()

    def nodes(self) -> Iterator[Node]:
        """All nodes, depth first, root included (the order of py_trees' ``iterate``)."""
        yield from iterate(self.root)

    @property
    def node_count(self) -> int:
        """Every node: root, composites, inverters, conditions and actions."""
        return sum(1 for _ in self.nodes())

    def node_types(self) -> dict[str, int]:
        """How many nodes of each type (for the node-distribution figures)."""
        counts = Counter(node.type for node in self.nodes())
        return {name: counts.get(name, 0) for name in NODE_TYPES}

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    def decide(self, features: np.ndarray) -> np.ndarray:
        """Decisions for a batch of states: ``features`` has exactly the shape
        ``(n, n_features)``, one row per state (:func:`tick` decides one state)."""
        x = np.asarray(features)
        if x.ndim != 2 or x.shape[1] != self.n_features:
            raise ValueError(f"decide takes a batch of shape (n, {self.n_features}), one row per "
                             f"state, got shape {x.shape}; for one state use tick(bt, state) or "
                             "bt.decide(state[None])")
        return decide_batch(self.root, x)

    def label(self, node: Node, precision: int = 4) -> str:
        """A readable label: ``pole_angle <= 0.05``, ``push_right``, ``Sequence``."""
        if isinstance(node, Condition):
            name = self.feature_names[node.feature]
            labels = dict(self.value_labels).get(node.feature)
            if labels:
                return _categorical_label(name, labels, node)
            return f"{name} {node.op} {_fmt(node.threshold, precision)}"
        if isinstance(node, Action):
            return self.action_names[node.action]
        return type(node).__name__

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of ``data/trees/`` (see :func:`from_dict`)."""
        extra = ({"value_labels": {self.feature_names[f]: list(v) for f, v in self.value_labels}}
                 if self.value_labels else {})
        return {
            "format": "ibt-behavior-tree/1",
            "feature_names": list(self.feature_names),
            "action_names": list(self.action_names),
            "tick_rule": (
                "condition succeeds iff float64(float32(obs[feature])) op threshold; an action "
                "succeeds and is the decision; selector/fallback succeed at the first success; "
                "sequence fails at the first failure; inverter flips"
            ),
            **extra,
            "root": node_to_dict(self.root),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, doc: Any) -> BehaviorTree:
        """Read a document of :meth:`to_dict`, strictly: ``ValueError`` names the first problem
        (missing or unknown keys, a fractional index, a non-finite threshold, an index out of
        range, a state that reaches no action; see :meth:`validate`)."""
        if not isinstance(doc, dict):
            raise ValueError(f"a behavior-tree document is a JSON object, got "
                             f"{type(doc).__name__}")
        missing = [key for key in ("feature_names", "action_names", "root") if key not in doc]
        if missing:
            raise ValueError(f"behavior-tree JSON lacks the key {missing[0]!r}; expected "
                             "feature_names, action_names and root")
        unknown = sorted(set(doc) - DOCUMENT_KEYS)
        if unknown:
            raise ValueError(f"unknown key {unknown[0]!r} in a behavior-tree document; expected "
                             f"{', '.join(sorted(DOCUMENT_KEYS))}")
        if doc.get("format", FORMAT) != FORMAT:
            raise ValueError(f"format {doc['format']!r} is not {FORMAT!r}, the one this version "
                             "reads")
        names = _names(doc["feature_names"], "feature_names")
        labels_doc = doc.get("value_labels", {})
        if not isinstance(labels_doc, dict):
            raise ValueError("value_labels must map feature names to lists of labels")
        labels = []
        for feature, values in labels_doc.items():
            if feature not in names:
                raise ValueError(f"value_labels names the feature {feature!r}, which is not in "
                                 "feature_names")
            labels.append((names.index(feature), _names(values, f"value_labels[{feature!r}]")))
        tree = cls(root=node_from_dict(doc["root"]), feature_names=names,
                   action_names=_names(doc["action_names"], "action_names"),
                   value_labels=tuple(labels))
        tree.validate()
        return tree

    @classmethod
    def from_json(cls, text: str) -> BehaviorTree:
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"not JSON ({err})") from None
        return cls.from_dict(doc)

    def validate(self) -> None:
        """Raise ``ValueError`` unless every feature and action index is in range, every
        composite has children, and every state provably reaches an action.

        The proof (:func:`unreached_state`) accepts a root that ends with an unguarded action
        (a default), tree-shaped Fallbacks whose last child always acts, and guards that
        together cover every state; a BT for which it finds a state reaching no action (which
        would send no decision to the environment) is refused with that state.
        """
        for node in self.nodes():
            if isinstance(node, Condition) and not node.feature < len(self.feature_names):
                raise ValueError(f"condition on feature {node.feature}, but the tree names "
                                 f"{len(self.feature_names)} features")
            if isinstance(node, Action) and not node.action < len(self.action_names):
                raise ValueError(f"action {node.action}, but the tree names "
                                 f"{len(self.action_names)} actions")
            if isinstance(node, Fallback | Sequence) and not node.children:
                raise ValueError(f"a {node.type} without children")
        state = unreached_state(self)
        if state is not None:
            where = ", ".join(f"{name}={value:.6g}"
                              for name, value in zip(self.feature_names, state, strict=True))
            found = decide_batch(self.root, state[None])[0] == NO_DECISION
            problem = (f"no action is reached on some states (e.g. {where})" if found else
                       f"cannot prove that every state reaches an action (the proof fails near "
                       f"{where})")
            raise ValueError(f"{problem}; end the root Selector with an unguarded default "
                             "action, or make the guards cover every state")


FORMAT = "ibt-behavior-tree/1"
DOCUMENT_KEYS = frozenset({"format", "feature_names", "action_names", "tick_rule",
                           "value_labels", "root"})


def _names(values: Any, what: str) -> tuple[str, ...]:
    """A non-empty list of distinct non-empty strings, as a tuple."""
    if (not isinstance(values, list) or not values
            or not all(isinstance(v, str) and v for v in values)):
        raise ValueError(f"{what} must be a non-empty list of non-empty strings")
    if len(set(values)) != len(values):
        repeated = next(v for v in values if values.count(v) > 1)
        raise ValueError(f"{what} names {repeated!r} twice")
    return tuple(values)


def _categorical_label(name: str, labels: tuple[str, ...], node: Condition) -> str:
    """``carrying == heavy`` / ``location in {depot, zone_a}`` for integer-coded categories."""
    cut = int(np.floor(node.threshold))  # x <= t  <=>  x in 0..cut for integer x
    below, above = labels[: cut + 1], labels[cut + 1:]
    chosen = below if node.op == "<=" else above
    other = above if node.op == "<=" else below
    if len(chosen) == 1:
        return f"{name} == {chosen[0]}"
    if len(other) == 1:
        return f"{name} != {other[0]}"
    return f"{name} in {{{', '.join(chosen)}}}"


def _fmt(value: float, precision: int) -> str:
    text = f"{value:.{precision}g}"
    return text


def iterate(node: Node) -> Iterator[Node]:
    """Depth-first, parent before children."""
    yield node
    for child in getattr(node, "children", ()):
        yield from iterate(child)


# ----------------------------------------------------------------------------------- JSON
def node_to_dict(node: Node) -> dict[str, Any]:
    if isinstance(node, Condition):
        return {"type": "condition", "feature": node.feature, "op": node.op,
                "threshold": float(node.threshold)}
    if isinstance(node, Action):
        return {"type": "action", "action": node.action}
    return {"type": node.type, "children": [node_to_dict(c) for c in node.children]}


_NODE_KEYS = {"condition": {"type", "feature", "op", "threshold"}, "action": {"type", "action"},
              **{kind: {"type", "children"}
                 for kind in ("selector", "fallback", "sequence", "inverter")}}
_COMPOSITES: dict[str, type[Selector | Fallback | Sequence]] = {
    "selector": Selector, "fallback": Fallback, "sequence": Sequence}


def node_from_dict(doc: Any, where: str = "root") -> Node:
    """One node of the JSON format, strictly; errors say where (``root.children[2]``)."""
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: a node is a JSON object, got {type(doc).__name__}")
    kind = doc.get("type")
    if kind not in _NODE_KEYS:
        raise ValueError(f"{where}: unknown node type {kind!r}; expected one of "
                         f"{', '.join(NODE_TYPES)}")
    keys = _NODE_KEYS[kind]
    if set(doc) != keys:
        problem = (f"lacks {sorted(keys - set(doc))[0]!r}" if keys - set(doc)
                   else f"has the unknown key {sorted(set(doc) - keys)[0]!r}")
        raise ValueError(f"{where}: a {kind} node {problem}; its keys are "
                         f"{', '.join(sorted(keys))}")
    try:
        if kind == "condition":
            return Condition(doc["feature"], doc["op"], doc["threshold"])
        if kind == "action":
            return Action(doc["action"])
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    if not isinstance(doc["children"], list):
        raise ValueError(f"{where}: children must be a list of nodes")
    children = tuple(node_from_dict(c, f"{where}.children[{i}]")
                     for i, c in enumerate(doc["children"]))
    if kind == "inverter":
        if len(children) != 1:
            raise ValueError(f"{where}: an inverter has exactly one child, got {len(children)}")
        return Inverter(children[0])
    if not children:
        raise ValueError(f"{where}: a {kind} needs at least one child")
    return _COMPOSITES[kind](children)


def indexed(root: Node) -> list[tuple[Node, tuple[int, ...]]]:
    """Every node in depth-first order with the positions of its children in that order.

    Positions come from one traversal, so a node object used twice in a tree (frozen
    dataclasses: equal nodes may be one object) gets two positions; this is how traces and
    drawings name nodes.
    """
    out: list[tuple[Node, tuple[int, ...]]] = []

    def walk(node: Node) -> int:
        position = len(out)
        out.append((node, ()))
        kids = tuple(walk(child) for child in getattr(node, "children", ()))
        out[position] = (node, kids)
        return position

    walk(root)
    return out


# --------------------------------------------------------------------------- reachability
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


def _truth(node: Node, negate: bool = False) -> list[Box] | None:
    """Where an action-free subtree succeeds (fails, if ``negate``); None if too large."""
    if isinstance(node, Condition):
        t = _snap(node.threshold)
        below = (node.op == "<=") != negate
        return [{node.feature: (-math.inf, t) if below else (t, math.inf)}]
    if isinstance(node, Inverter):
        return _truth(node.child, not negate)
    parts = [_truth(child, negate) for child in getattr(node, "children", ())]
    if isinstance(node, Sequence) != negate:  # a conjunction
        out: list[Box] | None = [{}]
        for part in parts:
            out = _and(out, part)
        return out
    if any(part is None for part in parts):
        return None
    union = [box for part in parts for box in part or ()]
    return union if len(union) <= MAX_BOXES else None


def _acting(node: Node, memo: dict[int, _Facts]) -> list[Box]:
    """States on which a tick of ``node`` surely reaches an action (an under-approximation)."""
    facts = _facts(node, memo)
    if facts.acts:
        return [{}]
    if isinstance(node, Inverter):
        return _acting(node.child, memo)
    if not isinstance(node, Fallback | Sequence):
        return []
    sequence = isinstance(node, Sequence)
    out: list[Box] = []
    reach: list[Box] | None = [{}]  # states that reach this child or have already acted
    for child in node.children:
        acting = _acting(child, memo)
        out += [m for r in reach or () for b in acting if (m := _meet(r, b)) is not None]
        kid = _facts(child, memo)
        if not kid.has_action:
            reach = _and(reach, _truth(child, negate=not sequence))
        elif not (kid.succeeds if sequence else kid.guarded):
            break
        if not reach or len(out) > MAX_BOXES:
            break
    return out


def _contains(box: Box, region: Box) -> bool:
    full = (-math.inf, math.inf)
    return all(lo <= region.get(f, full)[0] and region.get(f, full)[1] <= hi
               for f, (lo, hi) in box.items())


def _uncovered(boxes: list[Box]) -> Box | None:
    """A region no box touches, or None when the boxes cover every state."""
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
        # split the region on a bound of the first box that cuts it
        for feature, (lo, hi) in live[0].items():
            rlo, rhi = region.get(feature, full)
            cut = lo if rlo < lo < rhi else hi if rlo < hi < rhi else None
            if cut is not None:
                stack.append(({**region, feature: (cut, rhi)}, live))
                stack.append(({**region, feature: (rlo, cut)}, live))
                break
    return None


def unreached_state(tree: BehaviorTree) -> np.ndarray | None:
    """A state on which ticking ``tree`` reaches no action, or None when every state (every
    float32 observation) provably reaches one. Raises ``ValueError`` if the search gives up."""
    memo: dict[int, _Facts] = {}
    if _facts(tree.root, memo).acts:
        return None
    region = _uncovered(_acting(tree.root, memo))
    if region is None:
        return None
    state = np.zeros(tree.n_features, dtype=np.float32)
    for feature, (lo, hi) in region.items():
        state[feature] = hi if math.isfinite(hi) else (
            np.nextafter(np.float32(lo), np.float32(np.inf)) if math.isfinite(lo) else 0.0)
    return state


# ------------------------------------------------------------------------------ executors
def as_features(x: np.ndarray) -> np.ndarray:
    """Observations as the trees compare them: float32 values widened to float64."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def decide_batch(root: Node, features: np.ndarray) -> np.ndarray:
    """Vectorised tick of a batch ``(n, n_features)``; ``NO_DECISION`` where no action was
    reached (:meth:`BehaviorTree.validate` proves that this never happens)."""
    x = as_features(features)
    if x.ndim != 2:
        raise ValueError(f"decide_batch takes a batch of shape (n, n_features), got shape "
                         f"{x.shape}; for one state pass state[None]")
    decision = np.full(len(x), NO_DECISION, dtype=np.int64)
    _tick_mask(root, x, np.ones(len(x), dtype=bool), decision)
    return decision


def _tick_mask(node: Node, x: np.ndarray, active: np.ndarray, decision: np.ndarray) -> np.ndarray:
    """Tick ``node`` on the rows in ``active``; return the success mask (False off ``active``)."""
    if isinstance(node, Condition):
        column = x[:, node.feature]
        hit = column <= node.threshold if node.op == "<=" else column > node.threshold
        return active & hit
    if isinstance(node, Action):
        undecided = active & (decision == NO_DECISION)
        decision[undecided] = node.action
        return active.copy()
    if isinstance(node, Inverter):
        return active & ~_tick_mask(node.child, x, active, decision)
    if isinstance(node, Sequence):
        running = active.copy()
        for child in node.children:
            if not running.any():
                break
            running = _tick_mask(child, x, running, decision)
        return running
    # Selector / Fallback
    pending = active.copy()
    success = np.zeros_like(active)
    for child in node.children:
        if not pending.any():
            break
        ok = _tick_mask(child, x, pending, decision)
        success |= ok
        pending &= ~ok
    return success


@dataclass(frozen=True)
class TraceStep:
    """One ticked node: its depth-first index, depth, label and status."""

    index: int
    depth: int
    label: str
    success: bool


def tick(tree: BehaviorTree, features: Seq[float] | np.ndarray) -> tuple[int, list[TraceStep]]:
    """Tick one state (shape exactly ``(n_features,)``); return the decision and the trace of
    every node ticked, in order, each named by its depth-first position (:func:`indexed`)."""
    x = as_features(np.asarray(features))
    if x.shape != (tree.n_features,):
        raise ValueError(f"tick takes one state of shape ({tree.n_features},), got shape "
                         f"{x.shape}; for a batch use bt.decide(states)")
    nodes = indexed(tree.root)
    trace: list[TraceStep] = []
    decision = [NO_DECISION]

    def visit(position: int, depth: int) -> bool:
        node, children = nodes[position]
        if isinstance(node, Condition):
            value = x[node.feature]
            ok = bool(value <= node.threshold if node.op == "<=" else value > node.threshold)
        elif isinstance(node, Action):
            if decision[0] == NO_DECISION:
                decision[0] = node.action
            ok = True
        else:
            trace.append(TraceStep(position, depth, tree.label(node), False))
            slot = len(trace) - 1
            if isinstance(node, Inverter):
                ok = not visit(children[0], depth + 1)
            else:
                want = isinstance(node, Sequence)  # a sequence continues on success
                ok = want
                for child in children:
                    if visit(child, depth + 1) != want:
                        ok = not want
                        break
            trace[slot] = TraceStep(position, depth, trace[slot].label, ok)
            return ok
        trace.append(TraceStep(position, depth, tree.label(node), ok))
        return ok

    visit(0, 0)
    return decision[0], trace


# ------------------------------------------------------------------------------- py_trees
def to_py_trees(tree: BehaviorTree, features: np.ndarray | None = None):
    """The reference py_trees tree; conditions and actions read/write a shared blackboard dict.

    Returns ``(root, io)`` where ``io`` is a dict: set ``io["features"]`` before ticking, read
    ``io["decision"]`` after (``NO_DECISION`` when no action ran).
    """
    import py_trees

    io: dict[str, Any] = {"features": features, "decision": NO_DECISION,
                          "n_features": tree.n_features}
    Status = py_trees.common.Status

    class _Condition(py_trees.behaviour.Behaviour):
        def __init__(self, name: str, node: Condition) -> None:
            super().__init__(name)
            self.node = node

        def update(self):
            value = as_features(io["features"])[self.node.feature]
            hit = value <= self.node.threshold if self.node.op == "<=" else (
                value > self.node.threshold)
            return Status.SUCCESS if hit else Status.FAILURE

    class _Action(py_trees.behaviour.Behaviour):
        def __init__(self, name: str, node: Action) -> None:
            super().__init__(name)
            self.node = node

        def update(self):
            if io["decision"] == NO_DECISION:
                io["decision"] = self.node.action
            return Status.SUCCESS

    def build(node: Node):
        name = tree.label(node)
        if isinstance(node, Condition):
            return _Condition(name, node)
        if isinstance(node, Action):
            return _Action(name, node)
        if isinstance(node, Inverter):
            return py_trees.decorators.Inverter(name="Inverter", child=build(node.child))
        children = [build(c) for c in node.children]
        if isinstance(node, Sequence):
            return py_trees.composites.Sequence(name=name, memory=False, children=children)
        return py_trees.composites.Selector(name=name, memory=False, children=children)

    return build(tree.root), io


def py_trees_decide(root, io: dict[str, Any], features: np.ndarray) -> np.ndarray:
    """Tick a py_trees tree from :func:`to_py_trees` once per row of ``features``, a batch of
    shape exactly ``(n, n_features)``."""
    x = np.asarray(features)
    if x.ndim != 2 or x.shape[1] != io["n_features"]:
        raise ValueError(f"py_trees_decide takes a batch of shape (n, {io['n_features']}), got "
                         f"shape {x.shape}; for one state pass state[None]")
    out = np.empty(len(x), dtype=np.int64)
    for i, row in enumerate(x):
        io["features"] = row
        io["decision"] = NO_DECISION
        root.tick_once()
        out[i] = io["decision"]
    return out
