"""The size-retention front and Imitation-BT+: points, targets, costs, anchors."""

from __future__ import annotations

import pandas as pd
import pytest

import ibt
from ibt.engine import budgets
from ibt.evaluate.rollouts import retention_norm
from ibt.runs import front


def test_sweep_points_add_the_grid_budget_and_mark_it_as_the_grid_run():
    points = front.sweep_points(["CartPole-v1"], "dqn", ["bc"], {"CartPole-v1": [3, 12]}, [0])
    budget = ibt.get_task("CartPole-v1").budget.max_leaf_nodes
    assert [p.leaves for p in points] == [3, None]  # 12 is the budget: the grid run itself
    assert budget == 12


def test_plus_points_and_pending():
    points = front.plus_points({"CartPole-v1": ["dqn", "ppo"]}, {"CartPole-v1": 3}, "dqn",
                               {"CartPole-v1": [2, 3, None]}, [0, 1])
    assert {p.method for p in points} == {front.PLUS}
    assert sorted({(p.algo, p.leaves) for p in points}, key=str) == sorted(
        {("dqn", 3), ("dqn", 2), ("dqn", None), ("ppo", 3)}, key=str)
    assert len(points) == 8
    left = front.without_pending(points, [["CartPole-v1", "ppo"],
                                          ["CartPole-v1", "dqn", front.PLUS, 2]])
    assert {(p.algo, p.leaves) for p in left} == {("dqn", 3), ("dqn", None)}


def _rows(task: str, algo: str, leaves: int, retention: list[float], nodes: list[int]
          ) -> list[dict]:
    return [{"task": task, "expert": algo, "method": front.PLUS, "seed": s,
             "max_leaf_nodes": leaves, "retention_norm": r, "bt_nodes": n,
             "distill_seconds": 10.0, "refine_seconds": 5.0, "refine_episodes": 100,
             "refine_steps": 1000}
            for s, (r, n) in enumerate(zip(retention, nodes, strict=True))]


def test_target_table_verdicts():
    # Expect: met when both bars hold on the means; missed otherwise; absent -> not measured
    table = pd.DataFrame(
        _rows("MountainCar-v0", "dqn", 4, [99.0, 98.5, 97.0], [9, 9, 9])       # mean 98.2
        + _rows("MountainCar-v0", "dqn", 5, [99.5, 99.5, 99.5], [11, 11, 11])  # too big
        + _rows("CartPole-v1", "dqn", 3, [100.0, 100.0, 38.0], [6, 6, 5]))     # mean 79.3
    table = pd.concat([table, pd.DataFrame(_rows("highway-fast-v0", "dqn", 16, [90.0, 80.0],
                                                 [40, 50]))])
    out = front.target_table(table, {"MountainCar-v0": 4, "CartPole-v1": 3,
                                     "highway-fast-v0": None})
    verdict = {(r.task, r.expert): r.verdict for r in out.itertuples()}
    assert verdict[("MountainCar-v0", "dqn")] == "met"
    assert verdict[("CartPole-v1", "dqn")] == "missed"
    assert verdict[("CartPole-v1", "ppo")] == "not measured"
    assert verdict[("LunarLander-v3", "dqn")] == "not measured"
    mc = out[(out.task == "MountainCar-v0")].iloc[0]
    assert mc.best_fitting_limit == 4  # the 5-leaf BTs break the 9-node bar
    # a task without a bar is reported as measured, with its means
    hw = out[out.task == "highway-fast-v0"].iloc[0]
    assert (hw.verdict, hw.target, hw.retention_norm, hw.bt_nodes) == (
        "measured", "reported as measured", 85.0, 45.0)


def test_stage_seconds_count_a_plus_distillation_once_per_seed():
    table = pd.DataFrame(_rows("CartPole-v1", "dqn", 2, [99.0], [5])
                         + _rows("CartPole-v1", "dqn", 3, [99.0], [6]))
    cost = front.stage_seconds(table).iloc[0]
    assert cost.runs == 2
    assert cost.distill_hours == pytest.approx(10.0 / 3600)  # one seed, two leaf limits
    assert cost.refine_hours == pytest.approx(10.0 / 3600)


def test_anchors_are_converted_with_our_expert_and_random_returns(monkeypatch):
    monkeypatch.setattr(front, "expert_evaluation",
                        lambda cfg, task, algo: {"mean_return": 250.0})
    table = front.anchor_table(ibt.config("smoke"), [("LunarLander-v3", "dqn"),
                                                      ("CartPole-v1", "dqn")])
    assert set(table.task) == {"LunarLander-v3"}  # no published anchor for CartPole
    random_return = ibt.get_task("LunarLander-v3").random_return()
    mens = table[table.source == "MENS-DT-RL"]
    assert mens.retention_norm.iloc[0] == pytest.approx(
        retention_norm(240.6, 250.0, random_return))
    assert len(table) == 4  # MENS-DT-RL's tree and the zoo's three CART trees
    assert front.anchor_table(ibt.config("smoke"), []).columns.tolist()[:2] == ["source", "task"]


def test_smoke_refinement_budget_is_tiny_and_keeps_the_task_stages():
    cfg = ibt.config("smoke")
    config = budgets.refine_config(cfg, ibt.get_task("CartPole-v1"), max_leaves=3)
    assert config.episodes <= 240 and config.max_leaves == 3
    assert config.stages == ibt.get_task("CartPole-v1").refine.stages


def test_report_part_renders_targets_and_the_front(tmp_path):
    from ibt.report import beyond
    from ibt.report.stats import Results

    results = tmp_path / "results"
    results.mkdir()
    rows = (_rows("MountainCar-v0", "dqn", 4, [99.0, 98.5, 97.0], [9, 9, 9])
            + _rows("MountainCar-v0", "dqn", 2, [80.0, 85.0, 82.0], [5, 5, 5]))
    table = pd.DataFrame(rows)
    table.to_csv(results / "front.csv", index=False)
    front.target_table(table, {"MountainCar-v0": 4}).to_csv(results / "front_targets.csv",
                                                            index=False)
    text = beyond._front(Results(tmp_path))
    assert "| MountainCar-v0 | dqn | >= 98 % with <= 9 nodes | 4 | 3 | 98.2 (97.0) | 9.0 | met |" \
        in text
    assert "| MountainCar-v0 | imitation-bt+ | 9: 98.2 | 98.2 (9) |" in text
    assert "| LunarLander-v3 | dqn |" in text and "not measured" in text
    assert beyond._front(Results(tmp_path / "nothing")) is None


def test_front_axes_have_plain_few_ticks():
    # Expect: at most 6 plain-number ticks inside the data range, whatever the range
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ibt.report.figure_style import plain_log_ticks

    for low, high in [(4, 500), (38, 49), (5, 11), (2, 30)]:
        fig, ax = plt.subplots()
        ax.plot([low, high], [0, 1])
        ax.set_xscale("log")
        plain_log_ticks(ax)
        ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
        labels = [ax.xaxis.get_major_formatter()(t) for t in ticks]
        assert 3 <= len(ticks) <= 6, (low, high, ticks)
        assert all(label.isdigit() for label in labels), labels
        plt.close(fig)
