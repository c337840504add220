"""The executors of a Behavior Tree: ``tick`` (one state, with its trace), ``decide_batch`` (a
vectorised NumPy pass over many states) and ``to_py_trees`` (the reference library).

Comparisons are made in double precision on observations cast to float32 first, exactly as
scikit-learn's trees decide (see :mod:`ibt.bt.model`); a relational condition computes its
linear form from those doubles by the floating-point rule of :mod:`ibt.bt.linear`
(:meth:`ibt.bt.model.Condition.holds`, shared by the three executors).

**NaN and infinity have one meaning: they are refused.** Every executor reads observations
through :func:`as_features`, which raises :class:`NonFiniteObservation` (a ``ValueError``
naming the row and feature) when a value is NaN or infinite after the float32 cast (a finite
double beyond float32's range becomes infinite there). The same function is the input of the
compiled decision tree (:class:`ibt.evaluate.policies.CompiledTree`), of ``tick``,
``decide_batch`` and the py_trees executor here, and of the BehaviorTree.CPP engine
(:mod:`ibt.export.engine`); the verifier (:func:`ibt.synth.imitation.verify`) checks BTs on
finite states only. Why refuse rather than route: a NaN comparison is false, so ``x <= t`` and
``x > t`` both fail and a BT would reach no action where a tree goes right; any routing rule
would have to be copied exactly into the tree, every BT executor, the C++ ScriptConditions and
the coverage proof, while scikit-learn's own ``predict`` routes NaN by training-sample counts
and rejects infinity. A sensor that returns NaN is a fault to report, not a state to decide:
refusing it gives one clear error everywhere, and a BT that passes ``validate()`` then never
returns "no action".
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass
from typing import Any

import numpy as np

from ibt.bt.model import (
    NO_DECISION,
    Action,
    BehaviorTree,
    Condition,
    Inverter,
    Node,
    Sequence,
    indexed,
)


class NonFiniteObservation(ValueError):
    """An observation holding NaN or infinity (after the float32 cast): refused everywhere."""


def as_features(x: np.ndarray, *, finite: bool = True) -> np.ndarray:
    """Observations as the trees compare them: float32 values widened to float64; NaN and
    infinity refused (:class:`NonFiniteObservation`) unless ``finite=False`` (for proofs that
    reason about unbounded regions, never for observations)."""
    with np.errstate(over="ignore"):  # a double beyond float32's range becomes inf: refused
        out = np.asarray(x, dtype=np.float32).astype(np.float64)
    if finite and not np.isfinite(out).all():
        bad = np.argwhere(~np.isfinite(np.atleast_1d(out)))[0]
        where = f"feature {bad[-1]}" + (f" of row {bad[0]}" if bad.size > 1 else "")
        value = np.atleast_1d(out)[tuple(bad)]
        raise NonFiniteObservation(
            f"an observation holds {value} at {where} (after the float32 cast every executor "
            "makes); NaN and infinity have no decision: fix or filter the sensor that produced "
            "it")
    return out


def decide_batch(root: Node, features: np.ndarray, *, finite: bool = True) -> np.ndarray:
    """Vectorised tick of a batch ``(n, n_features)``; ``NO_DECISION`` where no action was
    reached (:meth:`BehaviorTree.validate` proves that this never happens on finite states;
    non-finite ones are refused unless ``finite=False``)."""
    x = as_features(features, finite=finite)
    if x.ndim != 2:
        raise ValueError(f"decide_batch takes a batch of shape (n, n_features), got shape "
                         f"{x.shape}; for one state pass state[None]")
    decision = np.full(len(x), NO_DECISION, dtype=np.int64)
    _tick_mask(root, x, np.ones(len(x), dtype=bool), decision)
    return decision


def _tick_mask(node: Node, x: np.ndarray, active: np.ndarray, decision: np.ndarray) -> np.ndarray:
    """Tick ``node`` on the rows in ``active``; return the success mask (False off ``active``)."""
    if isinstance(node, Condition):
        return active & node.holds(x)
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
            ok = bool(node.holds(x))
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
            hit = bool(self.node.holds(as_features(io["features"])))
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
