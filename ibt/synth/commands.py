"""Named commands: a regression tree's leaf vectors merged into a few commands.

A regression tree for continuous actions ends in leaves that each hold an action vector. To
read it as a BT, the leaves are merged into ``k`` commands by k-means on the leaf vectors
(each dimension scaled by its Box span, each leaf weighted by the training samples that reached
it), the centres rounded to ``decimals`` and clipped to the Box; leaves whose rounded centres
coincide share one command. The tree then becomes a ``DecisionTreeClassifier`` over command
ids with the same splits (:func:`command_tree`), which the registered synthesisers
(:mod:`ibt.synth.registry`) turn into verified BTs unchanged; the BT carries the command table
(:class:`ibt.bt.model.Commands`) and each action node is named by its command's values.

``k`` is chosen by return (:func:`choose_commands`): every ``k`` from 1 up to the number of
leaves is rolled out on the same held-out episodes, and the smallest ``k`` whose mean return is
at most ``tolerance`` (a share of expert minus random return) below the regression tree's own
is kept; ``k`` = the number of leaves loses only the rounding.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier, DecisionTreeRegressor

from ibt.bt.model import BehaviorTree, Commands
from ibt.evaluate.rollouts import rollout
from ibt.tasks.task import Task

DECIMALS = 2  #: command values are rounded to this many decimals (readable: 0.8, -0.35)


@dataclass(frozen=True)
class CommandTree:
    """A regression tree read as a classifier over commands, with its command table."""

    tree: DecisionTreeClassifier  # same splits as the regression tree; classes = command ids
    commands: Commands
    task: Task  # the discrete view the synthesisers take (action_names = command names)

    @property
    def n_commands(self) -> int:
        return len(self.commands.values)

    def actions(self, features: np.ndarray) -> np.ndarray:
        """The command vectors ``(n, dims)`` the tree sends on feature rows."""
        ids = self.tree.predict(np.asarray(features, dtype=np.float32)).astype(np.int64)
        return self.commands.array()[ids]

    def policy(self, task: Task):
        """``act`` on raw observations of the Box task."""
        return lambda obs: self.actions(task.features(obs))


def leaf_table(tree: DecisionTreeRegressor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The leaves' node ids, action vectors ``(leaves, dims)`` and weighted sample counts."""
    t = tree.tree_
    leaves = np.flatnonzero(t.children_left == -1)
    return leaves, t.value[leaves, :, 0].astype(np.float64), t.weighted_n_node_samples[leaves]


def command_name(task: Task, values: np.ndarray) -> str:
    """``main_engine 0.8, side_engine -0.35`` (units where the task names them)."""
    units = task.action_units or ("",) * task.n_actions
    return ", ".join(f"{name} {_number(v)}" + (f" {u}" if u else "")
                     for name, v, u in zip(task.action_names, values, units, strict=True))


def _number(value: float) -> str:
    """``0.8``, ``-1``, ``0`` (never ``-0``): at most :data:`DECIMALS` decimals, no trailing 0."""
    text = f"{float(value) + 0.0:.{DECIMALS}f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


def merge_leaves(tree: DecisionTreeRegressor, task: Task, k: int, *, seed: int = 0,
                 decimals: int = DECIMALS) -> tuple[np.ndarray, np.ndarray]:
    """Per leaf (in :func:`leaf_table` order) its command id, and the commands ``(k', dims)``
    (``k' <= k``: commands equal after rounding are one), ordered by first use in the tree."""
    from sklearn.cluster import KMeans

    _, values, visits = leaf_table(tree)
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    span = high - low
    if k >= len(values):
        centres, assignment = values, np.arange(len(values))
    else:
        km = KMeans(n_clusters=k, n_init=10, random_state=seed)
        km.fit((values - low) / span, sample_weight=visits)
        centres, assignment = km.cluster_centers_ * span + low, km.labels_
    rounded = np.clip(np.round(centres, decimals), low, high)
    # one id per distinct rounded command, numbered in order of first use by the leaves
    ids: dict[bytes, int] = {}
    table: list[np.ndarray] = []
    leaf_ids = np.empty(len(values), dtype=np.int64)
    for leaf, cluster in enumerate(assignment):
        key = rounded[cluster].tobytes()
        if key not in ids:
            ids[key] = len(table)
            table.append(rounded[cluster])
        leaf_ids[leaf] = ids[key]
    return leaf_ids, np.asarray(table)


def to_classifier(tree: DecisionTreeRegressor, leaf_ids: np.ndarray, n_commands: int
                  ) -> DecisionTreeClassifier:
    """A fitted ``DecisionTreeClassifier`` with ``tree``'s splits whose leaves predict
    ``leaf_ids`` (classes ``0..n_commands-1``); inner nodes hold their leaves' sample shares."""
    from sklearn.tree._tree import Tree

    state = tree.tree_.__getstate__()
    t = tree.tree_
    leaves, _, visits = leaf_table(tree)
    value = np.zeros((t.node_count, 1, n_commands))
    value[leaves, 0, leaf_ids] = visits
    for node in range(t.node_count - 1, -1, -1):  # children come after their parent
        left, right = t.children_left[node], t.children_right[node]
        if left != -1:
            value[node] = value[left] + value[right]
    value /= np.maximum(value.sum(axis=2, keepdims=True), 1e-300)
    new = Tree(tree.n_features_in_, np.array([n_commands], dtype=np.intp), 1)
    new.__setstate__({**state, "values": value})
    clf = DecisionTreeClassifier(max_leaf_nodes=tree.max_leaf_nodes, max_depth=tree.max_depth,
                                 random_state=tree.random_state)
    clf.n_features_in_ = tree.n_features_in_
    clf.n_outputs_ = 1
    clf.classes_ = np.arange(n_commands)
    clf.n_classes_ = n_commands
    clf.max_features_ = tree.max_features_
    clf.tree_ = new
    return clf


def command_tree(tree: DecisionTreeRegressor, task: Task, k: int, *, seed: int = 0,
                 decimals: int = DECIMALS) -> CommandTree:
    """``tree`` with its leaves merged into at most ``k`` named commands."""
    if not task.continuous:
        raise ValueError(f"{task.name} has discrete actions: its trees need no commands")
    if k < 1:
        raise ValueError(f"a tree needs at least one command, got k={k}")
    leaf_ids, table = merge_leaves(tree, task, k, seed=seed, decimals=decimals)
    names = tuple(command_name(task, row) for row in table)
    commands = Commands(task.action_names, task.action_units or ("",) * task.n_actions,
                        tuple(tuple(float(v) for v in row) for row in table))
    return CommandTree(to_classifier(tree, leaf_ids, len(table)), commands,
                       command_task(task, names))


def command_task(task: Task, names: tuple[str, ...]) -> Task:
    """The discrete view of a Box task whose actions are the commands ``names``."""
    return replace(task, action_names=names, action_low=(), action_high=(), action_units=())


def choose_commands(tree: DecisionTreeRegressor, task: Task, seeds: list[int], *,
                    scale: float, tolerance: float = 0.01, seed: int = 0,
                    decimals: int = DECIMALS) -> tuple[CommandTree, list[dict[str, Any]]]:
    """The smallest ``k`` whose held-out mean return is within ``tolerance * scale`` of the
    regression tree's (``scale``: expert minus random return), and every ``k`` measured."""
    from ibt.distill.continuous import box_tree_policy

    reference = rollout(task, box_tree_policy(task, tree), seeds).mean
    n_leaves = int(tree.get_n_leaves())
    rows: list[dict[str, Any]] = []
    chosen: CommandTree | None = None
    for k in range(1, n_leaves + 1):
        candidate = command_tree(tree, task, k, seed=seed, decimals=decimals)
        mean = rollout(task, candidate.policy(task), seeds).mean
        rows.append({"k": k, "commands": candidate.n_commands, "mean_return": mean,
                     "tree_return": reference, "loss": reference - mean})
        if reference - mean <= tolerance * abs(scale):
            chosen = candidate
            break
    if chosen is None:  # no k kept the return: every leaf its own (rounded) command
        chosen = candidate
    return chosen, rows


def with_commands(bt: BehaviorTree, commands: Commands) -> BehaviorTree:
    """``bt`` (over command ids) with its command table."""
    return replace(bt, commands=commands)


def bt_actions(bt: BehaviorTree, features: np.ndarray) -> np.ndarray:
    """The command vectors a BT with commands sends on feature rows."""
    if bt.commands is None:
        raise ValueError("this BT has discrete actions, not commands")
    x = np.asarray(features)
    if not bt.commands.linear:
        return bt.commands.array()[bt.decide(x)]
    widened = x.astype(np.float32).astype(np.float64)
    return bt.commands.evaluate(bt.decide(x), widened).astype(np.float32)


class CommandBTPolicy:
    """``act`` of a BT with commands on raw observations of its Box task; the task is checked
    first: its features and command dimensions are the BT's, every command inside its Box."""

    def __init__(self, task: Task, bt: BehaviorTree) -> None:
        if bt.commands is None or not task.continuous:
            raise ValueError("a BT with commands runs on a task with a Box action space")
        if (bt.feature_names, bt.commands.dimensions) != (task.feature_names, task.action_names):
            raise ValueError(f"the BT reads {', '.join(bt.feature_names)} and commands "
                             f"{', '.join(bt.commands.dimensions)}, but {task.name} has "
                             f"{', '.join(task.feature_names)} and {', '.join(task.action_names)}"
                             "; pass the task the BT was made for")
        if not bt.commands.linear:  # a linear command may leave the Box: the env clips it
            task.check_action(bt.commands.array())
        self.task, self.bt = task, bt

    def act(self, obs: np.ndarray) -> np.ndarray:
        return bt_actions(self.bt, self.task.features(obs))
