"""The paper grid's seeds per task, and which runs are still to compute (notebook 03's pending)."""

from __future__ import annotations

import ibt
from ibt.runs import grid


def test_highway_keeps_three_seeds_the_others_five():
    cells = grid.seed_budget(grid.grid(
        ["CartPole-v1", "highway-fast-v0"], ["dqn"], ["bc"], range(grid.PAPER_SEEDS)))
    seeds = {t: sorted(c.seed for c in cells if c.task.name == t)
             for t in ("CartPole-v1", "highway-fast-v0")}
    assert seeds == {"CartPole-v1": [0, 1, 2, 3, 4], "highway-fast-v0": [0, 1, 2]}


def test_uncached_lists_the_runs_not_in_the_cache(tmp_path):
    cfg = ibt.config("smoke", cache_dir=tmp_path / "cache")
    cells = grid.grid(["FrozenLake-v1"], ["dqn"], ["bc"], [0, 1])
    assert grid.uncached(cfg, cells) == cells
    grid.run_grid(cfg, cells[:1], n_jobs=1)
    assert grid.uncached(cfg, cells) == cells[1:]
