"""How fast each policy representation decides, and a BT compiled to plain Python.

:func:`compile_python` turns a synthesised BT into the source of one Python function (nested
``if`` statements, early returns), the fastest way to decide a single state in Python: what a
robot's control loop calls once per tick. :func:`benchmark` measures decisions per second of the
py_trees tree (the reference executor), the compiled function, the vectorised NumPy executor on
a batch, the scikit-learn tree and the SB3 expert, on single states and on batches.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from ibt.bt.executors import py_trees_decide, to_py_trees
from ibt.bt.model import (
    NO_DECISION,
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Node,
    Sequence,
)


class NotCompilable(ValueError):
    """The BT has a shape the code generator does not handle (an action not at a tail)."""


def _expr(node: Node) -> str:
    """A boolean Python expression for an action-free subtree."""
    if isinstance(node, Condition) and node.form is not None:  # the floating-point rule
        total = " + ".join(f"{w!r} * x[{i}]" for i, w in node.form.terms)
        return f"({total} {node.op} {node.threshold!r})"
    if isinstance(node, Condition):
        return f"(x[{node.feature}] {node.op} {node.threshold!r})"
    if isinstance(node, Inverter):
        return f"(not {_expr(node.child)})"
    if isinstance(node, Action):
        raise NotCompilable("an action inside a condition subtree")
    if not node.children:
        return "True" if isinstance(node, Sequence) else "False"
    joiner = " and " if isinstance(node, Sequence) else " or "
    return "(" + joiner.join(_expr(c) for c in node.children) + ")"


def _has_action(node: Node) -> bool:
    if isinstance(node, Action):
        return True
    return any(_has_action(c) for c in getattr(node, "children", ()))


def _emit(node: Node, indent: str, lines: list[str]) -> None:
    """Statements that return the decision if ``node`` reaches an action."""
    if isinstance(node, Action):
        lines.append(f"{indent}return {node.action}")
    elif isinstance(node, Sequence) and isinstance(node.children[-1], Action) and not any(
            _has_action(c) for c in node.children[:-1]):
        guard = " and ".join(_expr(c) for c in node.children[:-1]) or "True"
        lines.append(f"{indent}if {guard}:")
        lines.append(f"{indent}    return {node.children[-1].action}")
    elif isinstance(node, Fallback):
        for child in node.children:
            _emit(child, indent, lines)
    elif not _has_action(node):
        return  # ticked only for its status, which no decision depends on here
    else:
        raise NotCompilable(f"cannot compile a {node.type} with actions inside")


def python_source(bt: BehaviorTree, name: str = "decide") -> str:
    """The source of ``def decide(x) -> int`` (``x``: floats, float32 values widened)."""
    lines = [f"def {name}(x):"]
    _emit(bt.root, "    ", lines)
    lines.append(f"    return {NO_DECISION}")
    return "\n".join(lines) + "\n"


def compile_python(bt: BehaviorTree) -> Callable[[Any], int]:
    """A function deciding one state exactly as the BT (raises :class:`NotCompilable`)."""
    namespace: dict[str, Any] = {}
    exec(compile(python_source(bt), "<ibt-bt>", "exec"), namespace)
    decide = namespace["decide"]

    def run(state: Any) -> int:
        return decide(np.asarray(state, dtype=np.float32).astype(np.float64).tolist())

    run.source = python_source(bt)  # type: ignore[attr-defined]
    return run


def executors_agree(bt: BehaviorTree, tree: Any, states: np.ndarray,
                    py_trees_states: int | None = None) -> bool:
    """True when the NumPy BT, the compiled Python BT, the py_trees BT and the sklearn tree
    make the same decision on every row of ``states`` (py_trees on the first
    ``py_trees_states`` rows when given: it ticks about 10^4 states a second)."""
    from ibt.evaluate.policies import CompiledTree

    reference = CompiledTree(tree).predict(states)
    numpy_bt = bt.decide(states)
    compiled = compile_python(bt)
    python_bt = np.fromiter((compiled(row) for row in states), dtype=np.int64, count=len(states))
    root, io = to_py_trees(bt)
    subset = states if py_trees_states is None else states[:py_trees_states]
    ticked = py_trees_decide(root, io, subset)
    return bool(np.array_equal(reference, numpy_bt) and np.array_equal(reference, python_bt)
                and np.array_equal(reference[:len(subset)], ticked))


def _rate(fn: Callable[[], Any], decisions: int, min_seconds: float = 0.3) -> float:
    """Decisions per second of ``fn`` (repeated until ``min_seconds`` passed)."""
    fn()  # warm up
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return calls * decisions / elapsed


def benchmark(bt: BehaviorTree, tree: Any, expert: Any, states: np.ndarray, obs: np.ndarray,
              batch: int = 100_000) -> pd.DataFrame:
    """Decisions/s of every executor; ``states`` are feature rows, ``obs`` raw observations."""
    single = states[0]
    single_obs = obs[:1]
    compiled = compile_python(bt)
    root, io = to_py_trees(bt)
    big = np.resize(states, (batch, states.shape[1]))
    big_obs = np.resize(obs, (min(batch, 10_000), *obs.shape[1:]))
    rows = [
        ("py_trees BT", "single", _rate(lambda: py_trees_decide(root, io, single[None]), 1)),
        ("compiled Python BT", "single", _rate(lambda: compiled(single), 1)),
        ("NumPy BT", "single", _rate(lambda: bt.decide(single[None]), 1)),
        ("NumPy BT", "batch", _rate(lambda: bt.decide(big), len(big))),
        ("sklearn tree", "single", _rate(lambda: tree.predict(single[None]), 1)),
        ("sklearn tree", "batch", _rate(lambda: tree.predict(big), len(big))),
        ("SB3 expert predict", "single",
         _rate(lambda: expert.model.predict(single_obs, deterministic=True), 1)),
        ("SB3 expert predict", "batch",
         _rate(lambda: expert.model.predict(big_obs, deterministic=True), len(big_obs))),
    ]
    return pd.DataFrame(rows, columns=["executor", "mode", "decisions_per_second"])
