"""Looking inside distilled policies: decision grids over two features, paths on grid worlds.

These feed the qualitative figures (Figs. 7 and 8): where in the state space each action is
chosen, and which way a tree walks through FrozenLake.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise

import numpy as np
import pandas as pd

from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Selector, Sequence
from ibt.tasks.catalogue import Task

FROZENLAKE_OPTIMAL_PATHS = {
    "down first": (0, 4, 8, 9, 10, 14, 15),
    "right first": (0, 1, 2, 6, 10, 14, 15),
}
_FROZENLAKE_MOVES = {0: (0, -1), 1: (1, 0), 2: (0, 1), 3: (-1, 0)}  # left, down, right, up


def action_grid(decide: Callable[[np.ndarray], np.ndarray], x_range: tuple[float, float],
                y_range: tuple[float, float], n: int = 200) -> np.ndarray:
    """Actions of ``decide`` (feature rows -> actions) on an n x n grid; shape (n_y, n_x)."""
    xs = np.linspace(*x_range, n)
    ys = np.linspace(*y_range, n)
    xx, yy = np.meshgrid(xs, ys)
    states = np.column_stack([xx.ravel(), yy.ravel()]).astype(np.float32)
    return np.asarray(decide(states)).reshape(n, n)


def frozenlake_step(state: int, action: int, size: int = 4) -> int:
    """The next cell of the deterministic (non-slippery) lake; walls keep the agent in place."""
    row, col = divmod(state, size)
    d_row, d_col = _FROZENLAKE_MOVES[action]
    row = min(max(row + d_row, 0), size - 1)
    col = min(max(col + d_col, 0), size - 1)
    return row * size + col


def greedy_path(decide: Callable[[np.ndarray], np.ndarray], start: int = 0, goal: int = 15,
                max_steps: int = 30) -> list[int]:
    """The cells a deterministic FrozenLake policy visits from ``start`` (stops at the goal,
    a hole or a repeated cell)."""
    holes = {5, 7, 11, 12}
    path = [start]
    while len(path) <= max_steps and path[-1] != goal and path[-1] not in holes:
        nxt = frozenlake_step(path[-1], int(decide(np.array([[path[-1]]], np.float32))[0]))
        if nxt in path:
            path.append(nxt)
            break
        path.append(nxt)
    return path


def path_agreement(decide: Callable[[np.ndarray], np.ndarray], task: Task) -> pd.DataFrame:
    """For each optimal FrozenLake path: the policy's action in every cell and whether it
    follows that path (the paper: both shortest paths are encoded)."""
    rows = []
    for name, cells in FROZENLAKE_OPTIMAL_PATHS.items():
        for here, nxt in pairwise(cells):
            action = int(decide(np.array([[here]], np.float32))[0])
            rows.append({"path": name, "state": here, "action": task.action_names[action],
                         "follows_path": frozenlake_step(here, action) == nxt})
    return pd.DataFrame(rows)


def mountaincar_paper_rule(task: Task, position_op: str = ">") -> BehaviorTree:
    """The paper's MountainCar BT (its Fig. 8): push right when position > -0.96 or
    velocity > 0.002, else push left; built as a BT so it can be run and compared.

    ``position_op="<="`` gives the mirrored reading (right when position <= -0.96 or
    velocity > 0.002): taken literally the rule pushes right from every starting state.
    """
    position, velocity = task.feature_names.index("position"), task.feature_names.index(
        "velocity")
    left, right = task.action_names.index("left"), task.action_names.index("right")
    guard = Fallback((Condition(position, position_op, -0.96), Condition(velocity, ">", 0.002)))
    root = Selector((Sequence((guard, Action(right))), Action(left)))
    return BehaviorTree(root, task.feature_names, task.action_names)
