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

    type = "condition"


@dataclass(frozen=True)
class Action:
    """A leaf that succeeds and makes ``action`` the tick's decision."""

    action: int
    type = "action"


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

    def decide(self, features: np.ndarray) -> np.ndarray:
        """Decisions for a batch of feature vectors (shape ``(n, n_features)``)."""
        return decide_batch(self.root, features)

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
    def from_dict(cls, doc: dict[str, Any]) -> BehaviorTree:
        try:
            names = tuple(doc["feature_names"])
            labels = tuple((names.index(f), tuple(v))
                           for f, v in doc.get("value_labels", {}).items())
            tree = cls(
                root=node_from_dict(doc["root"]),
                feature_names=names,
                action_names=tuple(doc["action_names"]),
                value_labels=labels,
            )
        except KeyError as err:
            raise ValueError(f"behavior-tree JSON lacks the key {err}; expected "
                             "feature_names, action_names and root") from None
        tree.validate()
        return tree

    @classmethod
    def from_json(cls, text: str) -> BehaviorTree:
        return cls.from_dict(json.loads(text))

    def validate(self) -> None:
        """Raise ``ValueError`` if a feature or action index is out of range."""
        for node in self.nodes():
            if isinstance(node, Condition) and not 0 <= node.feature < len(self.feature_names):
                raise ValueError(f"condition on feature {node.feature}, but the tree names "
                                 f"{len(self.feature_names)} features")
            if isinstance(node, Action) and not 0 <= node.action < len(self.action_names):
                raise ValueError(f"action {node.action}, but the tree names "
                                 f"{len(self.action_names)} actions")


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


def node_from_dict(doc: dict[str, Any]) -> Node:
    kind = doc.get("type")
    if kind == "condition":
        return Condition(int(doc["feature"]), str(doc["op"]), float(doc["threshold"]))
    if kind == "action":
        return Action(int(doc["action"]))
    children = tuple(node_from_dict(c) for c in doc.get("children", ()))
    if kind == "inverter":
        if len(children) != 1:
            raise ValueError(f"an inverter has exactly one child, got {len(children)}")
        return Inverter(children[0])
    composites = {"selector": Selector, "fallback": Fallback, "sequence": Sequence}
    if kind not in composites:
        raise ValueError(f"unknown node type {kind!r}; expected one of {NODE_TYPES}")
    return composites[kind](children)


# ------------------------------------------------------------------------------ executors
def as_features(x: np.ndarray) -> np.ndarray:
    """Observations as the trees compare them: float32 values widened to float64."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def decide_batch(root: Node, features: np.ndarray) -> np.ndarray:
    """Vectorised tick of the whole batch; ``NO_DECISION`` where no action was reached."""
    x = as_features(np.atleast_2d(features))
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
    """Tick one state; return the decision and the trace of every node ticked, in order."""
    x = as_features(np.asarray(features).reshape(-1))
    index_of = {id(node): i for i, node in enumerate(tree.nodes())}
    trace: list[TraceStep] = []
    decision = [NO_DECISION]

    def visit(node: Node, depth: int) -> bool:
        if isinstance(node, Condition):
            value = x[node.feature]
            ok = bool(value <= node.threshold if node.op == "<=" else value > node.threshold)
        elif isinstance(node, Action):
            if decision[0] == NO_DECISION:
                decision[0] = node.action
            ok = True
        elif isinstance(node, Inverter):
            trace.append(TraceStep(index_of[id(node)], depth, tree.label(node), False))
            slot = len(trace) - 1
            ok = not visit(node.child, depth + 1)
            trace[slot] = TraceStep(trace[slot].index, depth, trace[slot].label, ok)
            return ok
        else:
            trace.append(TraceStep(index_of[id(node)], depth, tree.label(node), False))
            slot = len(trace) - 1
            want = isinstance(node, Sequence)  # a sequence continues on success
            ok = want
            for child in node.children:
                if visit(child, depth + 1) != want:
                    ok = not want
                    break
            trace[slot] = TraceStep(trace[slot].index, depth, trace[slot].label, ok)
            return ok
        trace.append(TraceStep(index_of[id(node)], depth, tree.label(node), ok))
        return ok

    visit(tree.root, 0)
    return decision[0], trace


# ------------------------------------------------------------------------------- py_trees
def to_py_trees(tree: BehaviorTree, features: np.ndarray | None = None):
    """The reference py_trees tree; conditions and actions read/write a shared blackboard dict.

    Returns ``(root, io)`` where ``io`` is a dict: set ``io["features"]`` before ticking, read
    ``io["decision"]`` after (``NO_DECISION`` when no action ran).
    """
    import py_trees

    io: dict[str, Any] = {"features": features, "decision": NO_DECISION}
    Status = py_trees.common.Status

    class _Condition(py_trees.behaviour.Behaviour):
        def __init__(self, name: str, node: Condition) -> None:
            super().__init__(name)
            self.node = node

        def update(self):
            value = as_features(np.asarray(io["features"]).reshape(-1))[self.node.feature]
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
    """Tick a py_trees tree from :func:`to_py_trees` once per row of ``features``."""
    out = np.empty(len(features), dtype=np.int64)
    for i, row in enumerate(np.atleast_2d(features)):
        io["features"] = row
        io["decision"] = NO_DECISION
        root.tick_once()
        out[i] = io["decision"]
    return out
