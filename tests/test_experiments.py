"""Grids: cells, bootstrap intervals, and identical rows locally and on a Dask cluster."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import ibt
from ibt.runs.grid import Cell, bootstrap_ci, grid, run_grid, summarise
from ibt.tasks.catalogue import get_task

TINY = {"n_iterations": 2, "labels_per_iteration": 100, "selection_episodes": 2}


def test_grid_is_the_full_cross_product():
    cells = grid(["CartPole-v1"], ["ppo", "a2c"], ["bc", "imitation-bt"], [0, 1, 2])
    assert len(cells) == 12
    assert len(set(cells)) == 12
    assert Cell(get_task("CartPole-v1"), "ppo", "bc", 0) in cells


def test_bootstrap_ci_brackets_the_mean_and_shrinks_with_data():
    rng = np.random.default_rng(0)
    small = rng.normal(50, 10, size=5)
    large = rng.normal(50, 10, size=500)
    lo_s, hi_s = bootstrap_ci(small)
    lo_l, hi_l = bootstrap_ci(large)
    assert lo_s <= small.mean() <= hi_s
    assert lo_l <= large.mean() <= hi_l
    assert hi_l - lo_l < hi_s - lo_s
    assert bootstrap_ci([3.0]) == (3.0, 3.0)


def test_summarise_groups_rows():
    rows = pd.DataFrame({"task": ["t"] * 4, "expert": ["ppo"] * 4, "method": ["bc", "bc", "v", "v"],
                         "retention_norm": [90.0, 100.0, 50.0, 70.0], "nodes": [3, 5, 7, 9]})
    out = summarise(rows).set_index("method")
    assert out.loc["bc", "retention_norm"] == 95.0
    assert out.loc["v", "nodes"] == 8.0
    assert out.loc["bc", "n"] == 2


def test_local_and_dask_grids_give_identical_rows(tmp_path):
    pytest.importorskip("dask.distributed")
    from dask.distributed import LocalCluster

    cfg = ibt.config("smoke", cache_dir=tmp_path / "local", final_episodes=3, progress=False)
    cells = grid(["CartPole-v1"], ["ppo"], ["bc", "imitation-bt"], [0], **TINY)
    local = run_grid(cfg, cells, n_jobs=1)
    cluster_cfg = ibt.config("smoke", cache_dir=tmp_path / "dask", final_episodes=3,
                             progress=False)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        remote = run_grid(cluster_cfg, cells, scheduler=cluster.scheduler_address)
    timing = ["wall_seconds"]
    pd.testing.assert_frame_equal(local.drop(columns=timing), remote.drop(columns=timing))
    # from the cache the rows are identical to the last digit, timing included (stable CSVs)
    pd.testing.assert_frame_equal(local, run_grid(cfg, cells, n_jobs=1))
    assert set(local.method) == {"bc", "imitation-bt"}
    assert (local.expert_labels >= 2 * TINY["labels_per_iteration"]).all()


def test_synthesize_grid_verifies_every_bt_and_rolls_out_the_seed_best(tmp_path):
    from ibt.runs.grid import node_table, retention_table, synthesize_grid

    cfg = ibt.config("smoke", cache_dir=tmp_path / "cache", data_dir=tmp_path / "data")
    cells = grid(["FrozenLake-v1"], ["dqn"], ["bc", "imitation-bt"], [0, 1])
    results = run_grid(cfg, cells, n_jobs=1)
    synthesis = synthesize_grid(cfg, results)
    assert sorted(synthesis.method.unique()) == ["bt-espresso", "decision-list", "imitation-bt",
                                                 "re-bt-espresso"]
    assert len(synthesis) == 8 and (synthesis.states_checked > 0).all()
    assert (synthesis.tree_splits == (synthesis.tree_nodes - 1) // 2).all()
    best = synthesis[synthesis.seed_best]
    assert len(best) == 4 and best.matches_tree.all()
    assert (best.evaluated == "BT rollout").all()
    # every written BT decides exactly as the tree it came from (checked here, not read from
    # the table's `equivalent` column, which holds True whenever a row exists)
    from ibt.synth.imitation import verify

    for row in best.itertuples():
        bt = ibt.load_json(cfg.data_dir / "trees" / "FrozenLake-v1" / "dqn" / f"{row.method}.json")
        tree = ibt.distill_cached(cfg, "FrozenLake-v1", "dqn", row.source_method,
                                  int(row.seed)).best_tree
        assert verify(bt, tree, ibt.get_task("FrozenLake-v1")) > 0
    # a BT plays its tree's episodes, so the baselines' retention is their BC tree's
    merged = synthesis[synthesis.method == "bt-espresso"].merge(
        results[results.method == "bc"], on="seed", suffixes=("", "_tree"))
    assert np.allclose(merged.mean_return, merged.mean_return_tree)
    assert set(retention_table(results, synthesis).method) == {
        "bc", "imitation-bt", "bt-espresso", "re-bt-espresso"}
    nodes = node_table(results, synthesis)
    assert set(nodes.method) == {"bc", "imitation-bt", "bt-espresso", "re-bt-espresso",
                                 "decision-list"}
    again = synthesize_grid(cfg, results)  # cached: identical
    pd.testing.assert_frame_equal(synthesis, again)
