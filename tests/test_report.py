"""The reproduction report: verdicts follow the numbers, missing results say so."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from ibt import report


def _grid(retention: dict[tuple[str, str, str], float]) -> pd.DataFrame:
    rows = []
    for (task, expert, method), value in retention.items():
        for seed in range(3):
            rows.append({"task": task, "expert": expert, "method": method, "seed": seed,
                         "mean_return": value, "std_return": 0.0, "expert_return": 100.0,
                         "retention_raw": value, "retention_norm": value + seed - 1,
                         "nodes": 15})
    return pd.DataFrame(rows)


def _write(tmp_path, name, frame):
    out = tmp_path / "results"
    out.mkdir(exist_ok=True)
    frame.to_csv(out / f"{name}.csv", index=False)


def test_missing_results_are_not_measured(tmp_path):
    res = report.Results(tmp_path)
    table = report.claims(res)
    assert len(table) == len(report.CLAIMS)
    assert (table.verdict == "not measured").all()
    assert "Reproduction report" in report.report_markdown(res)


@pytest.mark.parametrize(("value", "verdict"), [(99.5, "reproduced"), (95.0, "partly"),
                                                (60.0, "not reproduced")])
def test_simple_task_verdict_follows_the_numbers(tmp_path, value, verdict):
    _write(tmp_path, "distillation", _grid({("CartPole-v1", "dqn", "imitation-bt"): value,
                                            ("CartPole-v1", "dqn", "bc"): 50.0}))
    claim = report.claim_simple_tasks(report.Results(tmp_path))
    assert claim.verdict == verdict
    assert "CartPole-v1" in claim.measured


def test_beta_claim_compares_linear_with_the_best_exponential(tmp_path):
    rows = [{"task": "LunarLander-v3", "expert": "ppo", "schedule": s, "seed": k,
             "mean_return": base + k} for s, base in [("linear", 200), ("exponential p=0.5", 150)]
            for k in range(5)]
    _write(tmp_path, "beta_analysis", pd.DataFrame(rows))
    assert report.claim_beta(report.Results(tmp_path)).verdict == "reproduced"
    rows = [dict(r, mean_return=r["mean_return"] + (100 if r["schedule"] != "linear" else 0))
            for r in rows]
    _write(tmp_path, "beta_analysis", pd.DataFrame(rows))
    assert report.claim_beta(report.Results(tmp_path)).verdict == "not reproduced"


def test_node_claim_needs_ten_times_on_lunarlander(tmp_path):
    def syn(ratio):
        return pd.DataFrame([
            {"task": t, "expert": "ppo", "method": m, "seed": 0, "nodes": n}
            for t in ("LunarLander-v3", "CartPole-v1")
            for m, n in [("imitation-bt", 10), ("re-bt-espresso", 10 * ratio),
                         ("bt-espresso", 12 * ratio)]])
    _write(tmp_path, "synthesis", syn(12))
    assert report.claim_nodes(report.Results(tmp_path)).verdict == "reproduced"
    _write(tmp_path, "synthesis", syn(3))
    assert report.claim_nodes(report.Results(tmp_path)).verdict == "partly"


def test_readme_block_replaces_only_the_marked_section(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"# T\nbefore\n{report.README_BEGIN}\nold\n{report.README_END}\nafter\n")
    assert report.update_readme(readme, f"{report.README_BEGIN}\nnew\n{report.README_END}")
    text = readme.read_text()
    assert "new" in text and "old" not in text and text.endswith("after\n")
    assert not report.update_readme(readme, f"{report.README_BEGIN}\nnew\n{report.README_END}")
    (tmp_path / "bad.md").write_text("no markers")
    with pytest.raises(ValueError, match="markers"):
        report.update_readme(tmp_path / "bad.md", "x")


def test_timings_read_the_make_figures_record(tmp_path):
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "make_figures.json").write_text(
        json.dumps({"seconds": 123.4, "machine": "x86_64, 2 cores", "date": "2026-11-22"}))
    assert "123 s" in report.timings_markdown(report.Results(tmp_path))


def test_cells_below_the_minimum_seeds_say_how_many_they_have():
    from ibt.report import _cell

    assert _cell(pd.DataFrame({"retention_norm": [97.25]})) == "97.2 (1 seed)"
    assert _cell(pd.DataFrame({"retention_norm": [97.0, 99.0]})).endswith("] (2 seeds)")
    assert "seed" not in _cell(pd.DataFrame({"retention_norm": [97.0, 98.0, 99.0]}))
    assert _cell(pd.DataFrame({"retention_norm": [90.0, 100.0]})).startswith("95.0 [")


def test_a_tie_with_the_best_method_counts_as_best_on_stochastic_tasks(tmp_path):
    cells = {(task, "ppo", method): 100.0 for task in report.STOCHASTIC_TASKS
             for method in ("bc", "viper", "imitation-bt")}
    _write(tmp_path, "distillation", _grid(cells))
    assert report.claim_stochastic(report.Results(tmp_path)).verdict == "reproduced"
    cells[("highway-fast-v0", "ppo", "viper")] = 101.0
    _write(tmp_path, "distillation", _grid(cells))
    claim = report.claim_stochastic(report.Results(tmp_path))
    assert claim.verdict == "partly" and "best viper" in claim.measured
