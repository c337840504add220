"""The Imitation-BT+S table of the report: verdicts against the bar each row carries."""

from __future__ import annotations

import pandas as pd

from ibt.report.beyond import structure_markdown
from ibt.report.stats import Results
from ibt.runs.front import bar_of


def _rows(means: list[float], nodes: int | list[int], share: float, limit: int = 22
          ) -> list[dict]:
    counts = nodes if isinstance(nodes, list) else [nodes] * len(means)
    return [{"task": "LunarLander-v3", "expert": "dqn", "max_leaf_nodes": limit, "seed": s,
             "tree_leaves": limit, "bt_nodes": n, "episodes": 1000, "mean_return": m,
             "std_return": 50.0, "share_at_threshold": share, "threshold": 200.0,
             "cpu_seconds": 600.0, "env_steps": 10**7, "search_steps_per_second": 20000,
             "random_steps_per_second": 40000, **bar_of("LunarLander-v3", limit)}
            for s, (m, n) in enumerate(zip(means, counts, strict=True))]


def _table(tmp_path, rows: list[dict]) -> str:
    (tmp_path / "results").mkdir(exist_ok=True)
    pd.DataFrame(rows).to_csv(tmp_path / "results" / "front_protocol.csv", index=False)
    text = structure_markdown(Results(tmp_path))
    assert text is not None
    return text


def test_a_run_above_the_anchor_at_its_size_is_met(tmp_path):
    text = _table(tmp_path, _rows([245.0, 250.0, 242.0], nodes=41, share=0.93))
    assert text.splitlines()[-1].endswith("| met |")
    assert "MENS-DT-RL" in text


def test_too_many_nodes_or_too_few_good_landings_is_missed(tmp_path):
    assert _table(tmp_path, _rows([250.0] * 3, nodes=60, share=0.95)).endswith("| missed |")
    assert _table(tmp_path, _rows([250.0] * 3, nodes=40, share=0.85)).endswith("| missed |")
    assert _table(tmp_path, _rows([230.0] * 3, nodes=40, share=0.95)).endswith("| missed |")


def test_one_seed_over_the_node_bar_misses_even_when_the_mean_is_under_it(tmp_path):
    assert _table(tmp_path, _rows([250.0] * 3, nodes=[30, 30, 50], share=0.95)
                  ).endswith("| missed |")


def test_fewer_seeds_than_the_bar_asks_are_missed(tmp_path):
    assert _table(tmp_path, _rows([250.0] * 2, nodes=40, share=0.95)).endswith("| missed |")


def test_small_limits_are_judged_by_the_small_bt_bar_not_the_anchor(tmp_path):
    text = _table(tmp_path, _rows([205.0, 201.0, 200.0], nodes=[21, 18, 25], share=0.7,
                                  limit=8))
    assert text.endswith("| met |")
    assert "the small-BT bar" in text and "MENS-DT-RL" not in text
    assert _table(tmp_path, _rows([205.0] * 3, nodes=26, share=0.7, limit=12)
                  ).endswith("| missed |")


def test_a_limit_above_the_anchor_size_is_measured_not_judged(tmp_path):
    text = _table(tmp_path, _rows([250.0] * 3, nodes=60, share=0.95, limit=32))
    assert text.endswith("| measured |")


def test_absent_results_give_none(tmp_path):
    assert structure_markdown(Results(tmp_path)) is None
