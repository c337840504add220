"""A controller tree as a Behavior Tree: tests that read up to four features, commands that steer.

Each leaf of a :class:`ibt.distill.controller.ControllerArrays` becomes one rule, an ``Action``
whose command is the leaf's linear command (:class:`ibt.bt.model.Commands` with terms), which
BehaviorTree.CPP runs as one ``Script`` (``main_engine := -1.0 + 10.0 * y + -10.0 * vy``). Each
split becomes one condition: a plain feature test where it reads one feature with weight 1,
else a test of its weighted sum (:func:`ibt.bt.linear.linear_form`). The tree is laid out as
nested Fallbacks, each split ``Fallback(Sequence(test, one side), other side)`` with the side
that keeps the BT smaller first (a Fallback inside a Fallback, or a Sequence inside a Sequence,
is inlined), so a tree of ``L`` leaves has at most ``4L - 3`` nodes.

The construction decides exactly as the tree (same comparisons, same sums, the floating-point
rule of :mod:`ibt.bt.linear`); :func:`controller_bt` still checks it on the states given and
refuses a BT that sends another command on any of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ibt.bt.linear import linear_form
from ibt.bt.model import (
    Action,
    BehaviorTree,
    Commands,
    Condition,
    Fallback,
    Node,
    Selector,
    Sequence,
    iterate,
)
from ibt.distill.controller import ControllerArrays, widen
from ibt.distill.oblique import ObliqueArrays
from ibt.tasks.task import Task

SYNTHESISER = "controller"  #: the method's name in tables and reports


@dataclass(frozen=True)
class ControllerBT:
    """A verified BT of a controller tree and what the check saw."""

    bt: BehaviorTree
    states_checked: int
    disagreements: int

    @property
    def rules(self) -> int:
        """Action nodes (each a command ``Script`` in BehaviorTree.CPP)."""
        return sum(1 for node in self.bt.nodes() if isinstance(node, Action))


def split_condition(tree: ControllerArrays | ObliqueArrays, node: int, op: str) -> Condition:
    """The test of split ``node`` (``<=`` sends a state left)."""
    terms = [(int(f), float(tree.split[node, f])) for f in np.flatnonzero(tree.split[node])]
    threshold = float(tree.threshold[node])
    if len(terms) == 1 and terms[0][1] == 1.0:
        return Condition(terms[0][0], op, threshold)
    return Condition.relational(linear_form(terms), op, threshold)


def _size(nodes: list[Node]) -> int:
    return sum(sum(1 for _ in iterate(n)) for n in nodes)


def _sequence(parts: list[Node]) -> list[Node]:
    """A Sequence's children with inner Sequences inlined."""
    out: list[Node] = []
    for part in parts:
        out.extend(part.children if type(part) is Sequence else (part,))
    return out


def _alternatives(tree: ControllerArrays | ObliqueArrays, node: int,
                  leaf_action: dict[int, int]) -> list[Node]:
    """The children of a Fallback that decides as the subtree at ``node``."""
    if tree.left[node] == -1:
        return [Action(leaf_action[node])]
    left, right = int(tree.left[node]), int(tree.right[node])

    def body(child: int) -> Node:
        alternatives = _alternatives(tree, child, leaf_action)
        return alternatives[0] if len(alternatives) == 1 else Fallback(tuple(alternatives))

    options = []
    for op, first, second in (("<=", left, right), (">", right, left)):
        guarded = Sequence(tuple(_sequence([split_condition(tree, node, op), body(first)])))
        options.append([guarded, *_alternatives(tree, second, leaf_action)])
    return min(options, key=_size)


def leaf_commands(tree: ControllerArrays, task: Task) -> tuple[list[int], Commands]:
    """The leaves in depth-first order and their commands (one per leaf)."""
    order: list[int] = []
    stack = [0]
    while stack:
        node = stack.pop()
        if tree.left[node] == -1:
            order.append(node)
        else:
            stack.extend((int(tree.right[node]), int(tree.left[node])))
    values = tuple(tuple(float(v) + 0.0 for v in tree.bias[leaf]) for leaf in order)
    terms = tuple(tuple(tuple((int(f), float(tree.weights[leaf, d, f]))
                              for f in np.flatnonzero(tree.weights[leaf, d]))
                        for d in range(tree.n_dims)) for leaf in order)
    units = task.action_units or ("",) * task.n_actions
    return order, Commands(tuple(task.action_names), tuple(units), values, terms)


def rule_names(commands: Commands, task: Task) -> tuple[str, ...]:
    """Each rule named by what it sends (``main_engine := -1 + 10 * y - 10 * vy, side_engine :=
    0``), numbered where two read alike at four digits."""
    texts = [", ".join(commands.text(k, task.feature_names)) for k in range(len(commands.values))]
    return tuple(text if texts.count(text) == 1 else f"{text} (rule {k + 1})"
                 for k, text in enumerate(texts))


def controller_bt(tree: ControllerArrays | ObliqueArrays, task: Task, states: np.ndarray
                  ) -> ControllerBT:
    """The BT of ``tree`` on ``task``, checked on feature rows ``states``: ``ValueError`` if it
    sends another command (or action) than the tree on any of them (see the module
    docstring). An oblique tree's leaves are the task's actions."""
    x = widen(states)
    if isinstance(tree, ObliqueArrays):
        leaf_action = {int(leaf): int(tree.action[leaf]) for leaf in tree.leaves}
        root = Selector(tuple(_alternatives(tree, 0, leaf_action)))
        bt = BehaviorTree(root, tuple(task.feature_names), tuple(task.action_names),
                          task.value_labels)
        bt.validate()
        ours, theirs = bt.decide(x)[:, None], tree.decide(x)[:, None]
    else:
        order, commands = leaf_commands(tree, task)
        leaf_action = {leaf: k for k, leaf in enumerate(order)}
        root = Selector(tuple(_alternatives(tree, 0, leaf_action)))
        bt = BehaviorTree(root, tuple(task.feature_names), rule_names(commands, task),
                          commands=commands)
        bt.validate()
        ours = commands.evaluate(bt.decide(x), x)
        theirs = tree.decide(x)
    same = (ours == theirs) | (np.isnan(ours) & np.isnan(theirs))
    disagreements = int((~same.all(axis=1)).sum())
    if disagreements:
        raise ValueError(f"the BT of the controller tree sends another command on "
                         f"{disagreements} of {len(x)} states; it is not written")
    return ControllerBT(bt, len(x), disagreements)


def check_states(tree: ControllerArrays | ObliqueArrays, task: Task, visited: np.ndarray, *,
                 seed: int = 0, n_random: int = 2000) -> np.ndarray:
    """States to check a controller BT on: ``visited``, random states in the task's box, and
    each axis test's threshold and the float32 values on both sides of it."""
    rng = np.random.default_rng(seed)
    low = np.nan_to_num(np.asarray(task.low, dtype=np.float64), neginf=-10.0)
    high = np.nan_to_num(np.asarray(task.high, dtype=np.float64), posinf=10.0)
    low, high = np.maximum(low, -1e3), np.minimum(high, 1e3)
    random = rng.uniform(low, high, size=(n_random, len(low)))
    edges = []
    base = np.asarray(visited[:1] if len(visited) else random[:1], dtype=np.float32)
    for node in np.flatnonzero(tree.left != -1):
        features = np.flatnonzero(tree.split[node])
        if len(features) != 1:
            continue
        at = np.float32(tree.threshold[node])
        for value in (np.nextafter(at, np.float32(-np.inf)), at,
                      np.nextafter(at, np.float32(np.inf))):
            edge = base.copy()
            edge[0, features[0]] = value
            edges.append(edge)
    return np.concatenate([np.asarray(visited, dtype=np.float32),
                           random.astype(np.float32), *edges]).astype(np.float32)


def rules_text(bt: BehaviorTree) -> list[str]:
    """A controller BT as if/elif/else lines, one per rule, nested where the BT nests:
    ``if angular_velocity <= -2.7: torque := -2.96 + 6.66 * cos_theta``, then ``elif ...``
    lines, then ``else: ...`` for the default rule."""
    def block(children: tuple[Node, ...], indent: str) -> list[str]:
        lines: list[str] = []
        for k, child in enumerate(children):
            if isinstance(child, Action):
                keyword = "else" if k else "always"
                lines.append(f"{indent}{keyword}: {bt.label(child)}")
                continue
            parts = child.children if isinstance(child, Sequence) else (child,)
            tests = [bt.label(p) for p in parts if isinstance(p, Condition)]
            body = [p for p in parts if not isinstance(p, Condition)]
            head = f"{indent}{'elif' if k else 'if'} {' and '.join(tests) or 'true'}:"
            if len(body) == 1 and isinstance(body[0], Action):
                lines.append(f"{head} {bt.label(body[0])}")
            else:
                lines.append(head)
                for inner in body:
                    inner_children = inner.children if isinstance(inner, Fallback) else (inner,)
                    lines.extend(block(tuple(inner_children), indent + "    "))
        return lines

    root = bt.root
    return block(root.children if isinstance(root, Fallback) else (root,), "")
