"""Grid-world helpers and decision grids behind the qualitative figures."""

from __future__ import annotations

import numpy as np

from ibt.report.analysis import (
    FROZENLAKE_OPTIMAL_PATHS,
    action_grid,
    frozenlake_step,
    greedy_path,
    path_agreement,
)
from ibt.tasks.catalogue import get_task

# FrozenLake actions: 0 left, 1 down, 2 right, 3 up


def test_frozenlake_moves_match_gymnasium():
    env = get_task("FrozenLake-v1").make_env()
    terminal = {5, 7, 11, 12, 15}  # holes and goal: gymnasium keeps the agent there
    for state in sorted(set(range(16)) - terminal):
        for action in range(4):
            env.reset(seed=0)
            env.unwrapped.s = state
            nxt, *_ = env.step(action)
            assert frozenlake_step(state, action) == nxt


def test_greedy_path_follows_a_policy_and_stops():
    table = {0: 1, 4: 1, 8: 2, 9: 2, 10: 1, 14: 2}  # the "down first" path
    path = greedy_path(lambda s: np.array([table.get(int(s[0, 0]), 3)]))
    assert tuple(path) == FROZENLAKE_OPTIMAL_PATHS["down first"]
    looping = greedy_path(lambda s: np.array([0]))  # always left: stuck at 0
    assert looping == [0, 0]


def test_path_agreement_marks_each_step():
    table = {0: 1, 4: 1, 8: 2, 9: 2, 10: 1, 14: 2, 1: 2, 2: 1, 6: 1}
    frame = path_agreement(lambda s: np.array([table[int(s[0, 0])]]), get_task("FrozenLake-v1"))
    assert frame.groupby("path")["follows_path"].sum().to_dict() == {"down first": 6,
                                                                       "right first": 5}


def test_action_grid_shape_and_orientation():
    grid = action_grid(lambda s: (s[:, 0] > 0).astype(int), (-1, 1), (-2, 2), n=10)
    assert grid.shape == (10, 10)
    assert grid[:, 0].sum() == 0 and grid[:, -1].sum() == 10  # x grows along columns


def test_the_papers_mountaincar_rule_read_literally_always_pushes_right_at_the_start():
    import numpy as np

    import ibt
    from ibt.report.analysis import mountaincar_paper_rule

    car = ibt.get_task("MountainCar-v0")
    literal = mountaincar_paper_rule(car)
    mirrored = mountaincar_paper_rule(car, position_op="<=")
    starts = np.column_stack([np.linspace(-0.6, -0.4, 11), np.zeros(11)]).astype(np.float32)
    right = car.action_names.index("right")
    assert (literal.decide(starts) == right).all()
    assert (mirrored.decide(starts) == car.action_names.index("left")).all()
    assert literal.node_count == mirrored.node_count == 7
