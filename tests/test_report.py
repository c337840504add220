"""Statistics, claims and the report: verdicts follow the numbers, partial tables say "not
measured", experts that do not count stay out of every claim, intervals say what they are."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.report import beyond, claims, deviations, markdown, stats, tables
from ibt.report.claims import NOT_MEASURED, NOT_REPRODUCED, PARTLY, REPRODUCED

SIMPLE = claims.SIMPLE_TASKS
STOCHASTIC = claims.STOCHASTIC_TASKS


def _grid(retention: dict[tuple[str, str, str], float], seeds: int = 3) -> pd.DataFrame:
    """Rows of a distillation table: ``seeds`` runs per cell around the given mean."""
    rows = []
    for (task, expert, method), value in retention.items():
        offsets = np.linspace(-1, 1, seeds) if seeds > 1 else [0.0]
        for seed, off in enumerate(offsets):
            rows.append({"task": task, "expert": expert, "method": method, "seed": seed,
                         "mean_return": value, "std_return": 0.0, "expert_return": 100.0,
                         "retention_raw": value, "retention_norm": value + off, "nodes": 15})
    return pd.DataFrame(rows)


def _write(tmp_path, name, frame):
    out = tmp_path / "results"
    out.mkdir(exist_ok=True)
    frame.to_csv(out / f"{name}.csv", index=False)


def _experts(tmp_path, statuses: dict[tuple[str, str], str]):
    rows = [{"task": t, "algo": a, "timesteps": 1000, "net_arch": "64x64", "mean_return": 1.0,
             "meets_bar": s != "excluded", "status": s, "status_evidence": f"evidence {t} {a}",
             "hyperparams_source": "ours", "wall_seconds": 1.0}
            for (t, a), s in statuses.items()]
    (tmp_path / "experts").mkdir(exist_ok=True)
    pd.DataFrame(rows).to_csv(tmp_path / "experts" / "manifest.csv", index=False)


def _simple(value: float, worst: float | None = None) -> dict:
    cells = {(t, "dqn", "imitation-bt"): value for t in SIMPLE}
    if worst is not None:
        cells[(SIMPLE[0], "dqn", "imitation-bt")] = worst
    return cells


def _stochastic(ours: float, rival: float = 50.0, expert: str = "ppo") -> dict:
    return {(t, expert, m): (ours if m == "imitation-bt" else rival)
            for t in STOCHASTIC for m in claims.TREE_METHODS}


# --- stats ------------------------------------------------------------------------------------

def test_few_seeds_give_a_range_never_a_ci():
    iv = stats.interval([1.0, 5.0, 3.0])
    assert (iv.low, iv.high, iv.kind) == (1.0, 5.0, "range")
    assert iv.label == "range over 3 seeds" and "CI" not in iv.label
    iv = stats.interval([1.0, 2.0, 3.0, 4.0, 10.0])
    assert iv.kind == "ci" and iv.label == "95 % percentile bootstrap CI over 5 seeds"
    assert 1.0 <= iv.low <= iv.mean <= iv.high <= 10.0


def test_summarise_names_its_interval_per_row():
    frame = _grid({("A", "dqn", "bc"): 50.0}, seeds=3)
    frame = pd.concat([frame, _grid({("B", "dqn", "bc"): 60.0}, seeds=5)])
    summary = stats.summarise(frame).set_index("task")
    assert list(summary["interval"]) == ["range over 3 seeds",
                                         "95 % percentile bootstrap CI over 5 seeds"]
    assert "ci_low" not in summary and {"interval_low", "interval_high"} <= set(summary)
    assert summary.loc["A", "interval_low"] == 49.0
    caption = stats.error_bar_caption(summary.reset_index())
    assert "range over 3 seeds" in caption and "not a confidence interval" in caption


@settings(max_examples=30, deadline=None)
@given(st.lists(st.lists(st.floats(-100, 100), min_size=1, max_size=6), min_size=1,
                max_size=4))
def test_stratified_iqm_lies_within_the_data(cells):
    point, low, high = stats.stratified_iqm(cells, reps=200)
    flat = np.concatenate([np.asarray(c) for c in cells])
    assert flat.min() - 1e-9 <= low <= high <= flat.max() + 1e-9
    assert flat.min() - 1e-9 <= point <= flat.max() + 1e-9


def test_stratified_bootstrap_keeps_every_cell():
    # two cells far apart: a resample that dropped one cell would leave the other's value
    point, low, high = stats.stratified_iqm([[0.0] * 4, [100.0] * 4], reps=300)
    assert point == 50.0 and low == high == 50.0


# --- claims: not measured ---------------------------------------------------------------------

def test_missing_results_are_not_measured(tmp_path):
    res = stats.Results(tmp_path)
    table = claims.claims(res)
    assert len(table) == len(claims.CLAIMS)
    assert (table.verdict == NOT_MEASURED).all()
    text = markdown.report_markdown(res)
    assert "Reproduction report" in text and "not measured" in text


@pytest.mark.parametrize("claim", claims.CLAIMS, ids=lambda c: c.__name__)
def test_every_claim_says_not_measured_on_partial_tables(tmp_path, claim):
    # a distillation table without most tasks and methods, tables with missing columns
    _write(tmp_path, "distillation", _grid({("CartPole-v1", "dqn", "imitation-bt"): 99.0,
                                            ("LunarLander-v3", "dqn", "imitation-bt"): 50.0}))
    _write(tmp_path, "synthesis", pd.DataFrame({"task": ["CartPole-v1"], "expert": ["dqn"],
                                                "method": ["imitation-bt"], "nodes": [5]}))
    _write(tmp_path, "beta_analysis", pd.DataFrame({"schedule": ["linear"],
                                                    "mean_return": [1.0]}))
    _write(tmp_path, "qualitative", pd.DataFrame({"key": ["frozenlake_expert"],
                                                  "value": ["dqn"]}))
    _write(tmp_path, "package_delivery", pd.DataFrame({"experiment": ["dqn"],
                                                       "policy": ["expert"]}))
    result = claim(stats.Results(tmp_path))
    assert result.verdict == NOT_MEASURED, result
    assert result.measured.startswith("not measured")


def test_a_malformed_table_is_not_measured_not_a_crash(tmp_path):
    _write(tmp_path, "package_delivery", pd.DataFrame({
        "experiment": ["dqn"] * 3, "policy": ["expert", "imitation-bt", "re-bt-espresso"],
        "nodes": [1, "many", 9], "delivered": [1, 1, 1], "mean_return": [1, 1, 1],
        "retention_norm_%": [100, 100, 100]}))
    assert claims.claim_package_delivery(stats.Results(tmp_path)).verdict == NOT_MEASURED


# --- claims: every verdict branch -------------------------------------------------------------

@pytest.mark.parametrize(("value", "worst", "verdict"), [
    (99.5, None, REPRODUCED), (99.5, 95.0, PARTLY), (99.5, 60.0, NOT_REPRODUCED)])
def test_simple_task_verdicts(tmp_path, value, worst, verdict):
    _write(tmp_path, "distillation", _grid(_simple(value, worst)))
    claim = claims.claim_simple_tasks(stats.Results(tmp_path))
    assert claim.verdict == verdict
    assert "range over 3 seeds" in claim.measured and "CI" not in claim.measured


def test_simple_tasks_leave_out_experts_that_do_not_count(tmp_path):
    cells = _simple(99.5)
    cells[("PackageDelivery-v0", "a2c", "imitation-bt")] = 100.0
    cells[("CartPole-v1", "a2c", "imitation-bt")] = 20.0  # would fail the claim if counted
    _write(tmp_path, "distillation", _grid(cells))
    _experts(tmp_path, {("PackageDelivery-v0", "a2c"): "constant-action",
                        ("CartPole-v1", "a2c"): "excluded"})
    claim = claims.claim_simple_tasks(stats.Results(tmp_path))
    assert claim.verdict == REPRODUCED
    assert "6 of 6 cells" in claim.measured
    assert "left out: CartPole-v1/a2c (excluded), PackageDelivery-v0/a2c (constant-action)" \
        in claim.measured


def test_simple_tasks_with_only_excluded_experts_are_not_measured(tmp_path):
    _write(tmp_path, "distillation", _grid(_simple(99.5)))
    _experts(tmp_path, {(t, "dqn"): "excluded" for t in SIMPLE})
    assert claims.claim_simple_tasks(stats.Results(tmp_path)).verdict == NOT_MEASURED


@pytest.mark.parametrize(("ours", "rival", "verdict"), [
    (90.0, 50.0, REPRODUCED), (50.0, 90.0, NOT_REPRODUCED), (90.0, 90.0, REPRODUCED)])
def test_stochastic_verdicts(tmp_path, ours, rival, verdict):
    _write(tmp_path, "distillation", _grid(_stochastic(ours, rival)))
    claim = claims.claim_stochastic(stats.Results(tmp_path))
    assert claim.verdict == verdict  # a tie with the best counts as best
    assert "IQM over the 2 counted cells" in claim.measured


def test_stochastic_partly_counts_only_ok_experts(tmp_path):
    cells = {**_stochastic(90.0, 50.0, "ppo"), **_stochastic(40.0, 50.0, "dqn")}
    cells.update({("highway-fast-v0", "a2c", m): 100.0 for m in claims.TREE_METHODS})
    _write(tmp_path, "distillation", _grid(cells))
    _experts(tmp_path, {("highway-fast-v0", "a2c"): "constant-action"})
    claim = claims.claim_stochastic(stats.Results(tmp_path))
    assert claim.verdict == PARTLY
    assert "best in 2 of 4 counted cells" in claim.reason  # highway a2c's tie is not a win
    assert "highway-fast-v0/a2c (constant-action)" in claim.measured


def test_stochastic_needs_every_tree_method(tmp_path):
    cells = _stochastic(90.0)
    del cells[("LunarLander-v3", "ppo", "viper")]
    _write(tmp_path, "distillation", _grid(cells))
    claim = claims.claim_stochastic(stats.Results(tmp_path))
    assert claim.verdict == NOT_MEASURED and "viper" in claim.reason


@pytest.mark.parametrize(("rival_shift", "verdict"), [
    (-50, REPRODUCED), (0.5, PARTLY), (100, NOT_REPRODUCED)])
def test_beta_verdicts(tmp_path, rival_shift, verdict):
    rows = [{"task": "LunarLander-v3", "expert": "ppo", "schedule": s, "seed": k,
             "mean_return": 200 + k + (rival_shift if s != "linear" else 0)}
            for s in ("linear", "exponential p=0.5") for k in range(5)]
    _write(tmp_path, "beta_analysis", pd.DataFrame(rows))
    claim = claims.claim_beta(stats.Results(tmp_path))
    assert claim.verdict == verdict
    assert "95 % percentile bootstrap CI over 5 seeds" in claim.measured


def _synthesis(ratio: float, *, lunar: bool = True, ratio_elsewhere: float | None = None):
    tasks = (["LunarLander-v3"] if lunar else []) + ["CartPole-v1", "Acrobot-v1"]
    rows = []
    for t in tasks:
        r = ratio if t == "LunarLander-v3" or ratio_elsewhere is None else ratio_elsewhere
        rows += [{"task": t, "expert": "ppo", "method": m, "seed": 0, "nodes": n}
                 for m, n in [("imitation-bt", 10), ("re-bt-espresso", 10 * r),
                              ("bt-espresso", 12 * r)]]
    return pd.DataFrame(rows)


@pytest.mark.parametrize(("kwargs", "verdict"), [
    ({"ratio": 12}, REPRODUCED), ({"ratio": 3}, PARTLY),
    ({"ratio": 12, "ratio_elsewhere": 0.5}, NOT_REPRODUCED), ({"ratio": 12, "lunar": False},
                                                              NOT_MEASURED)])
def test_node_verdicts(tmp_path, kwargs, verdict):
    _write(tmp_path, "synthesis", _synthesis(**kwargs))
    assert claims.claim_nodes(stats.Results(tmp_path)).verdict == verdict


def test_node_claim_leaves_out_constant_action_experts(tmp_path):
    syn = pd.concat([_synthesis(12), _synthesis(1).assign(expert="a2c")])
    _write(tmp_path, "synthesis", syn)
    assert claims.claim_nodes(stats.Results(tmp_path)).verdict == PARTLY
    _experts(tmp_path, {(t, "a2c"): "constant-action" for t in syn.task.unique()})
    assert claims.claim_nodes(stats.Results(tmp_path)).verdict == REPRODUCED


def _lake(default="down", down=6, right=6, path="0-4-8-9-10-14-15"):
    return {"frozenlake_expert": "dqn", "frozenlake_bt_nodes": 9,
            "frozenlake_default_action": default, "frozenlake_path": path,
            "frozenlake_follows_down_first": down, "frozenlake_follows_right_first": right}


def _car(smallest: float | None):
    facts = {"mountaincar_expert": "dqn", "mountaincar_bt_nodes": 19,
             "mountaincar_bt_retention_norm": 99.9, "paper_rule_retention_norm": 0.0,
             "paper_rule_return": -200.0, "mirrored_rule_retention_norm": 69.6,
             "paper_rule_agreement": 48.2}
    front = pd.DataFrame({"task": ["MountainCar-v0"] * 2, "nodes": [5, smallest or 40],
                          "retention_norm": [50.0, 99.0 if smallest else 90.0],
                          "conditions": [2, 6]})
    return facts, front


def _qualitative(tmp_path, facts):
    _write(tmp_path, "qualitative", pd.DataFrame({"key": list(facts),
                                                  "value": [str(v) for v in facts.values()]}))


@pytest.mark.parametrize(("facts", "verdict"), [
    (_lake(), REPRODUCED), (_lake(default="right", right=4), PARTLY),
    (_lake(path="0-4-5"), NOT_REPRODUCED)])
def test_frozenlake_verdicts(tmp_path, facts, verdict):
    _qualitative(tmp_path, facts)
    claim = claims.claim_frozenlake(stats.Results(tmp_path))
    assert claim.verdict == verdict


def test_frozenlake_with_an_excluded_expert_is_not_measured(tmp_path):
    _qualitative(tmp_path, _lake())
    _experts(tmp_path, {("FrozenLake-v1", "dqn"): "excluded"})
    assert claims.claim_frozenlake(stats.Results(tmp_path)).verdict == NOT_MEASURED


@pytest.mark.parametrize(("smallest", "verdict"), [
    (7, REPRODUCED), (11, PARTLY), (None, NOT_REPRODUCED)])
def test_mountaincar_verdicts(tmp_path, smallest, verdict):
    facts, front = _car(smallest)
    _qualitative(tmp_path, facts)
    _write(tmp_path, "bt_size_front", front)
    claim = claims.claim_mountaincar(stats.Results(tmp_path))
    assert claim.verdict == verdict
    assert "BTs with <= 2 conditions reach 50.0" in claim.measured


def test_mountaincar_without_the_size_front_is_not_measured(tmp_path):
    _qualitative(tmp_path, _car(11)[0])
    assert claims.claim_mountaincar(stats.Results(tmp_path)).verdict == NOT_MEASURED


def _delivery(ours_nodes=100, base_nodes=200, ours_ret=99.0, base_ret=100.0, experts=("dqn",)):
    rows = []
    for e in experts:
        rows += [{"experiment": e, "policy": p, "nodes": n, "delivered": 30.0,
                  "mean_return": r * 2, "retention_norm_%": r}
                 for p, n, r in [("expert", np.nan, 100.0), ("imitation-bt", ours_nodes, ours_ret),
                                 ("re-bt-espresso", base_nodes, base_ret)]]
    return pd.DataFrame(rows)


@pytest.mark.parametrize(("kwargs", "verdict"), [
    ({}, REPRODUCED), ({"ours_ret": 80.0}, PARTLY), ({"ours_nodes": 300}, NOT_REPRODUCED)])
def test_package_delivery_verdicts(tmp_path, kwargs, verdict):
    _write(tmp_path, "package_delivery", _delivery(**kwargs))
    assert claims.claim_package_delivery(stats.Results(tmp_path)).verdict == verdict


def test_package_delivery_skips_experts_that_do_not_count(tmp_path):
    perf = pd.concat([_delivery(), _delivery(ours_nodes=300, experts=("a2c",))])
    _write(tmp_path, "package_delivery", perf)
    assert claims.claim_package_delivery(stats.Results(tmp_path)).verdict == NOT_REPRODUCED
    _experts(tmp_path, {("PackageDelivery-v0", "a2c"): "excluded"})
    claim = claims.claim_package_delivery(stats.Results(tmp_path))
    assert claim.verdict == REPRODUCED and "left out: a2c" in claim.measured
    _experts(tmp_path, {("PackageDelivery-v0", e): "excluded" for e in ("a2c", "dqn")})
    assert claims.claim_package_delivery(stats.Results(tmp_path)).verdict == NOT_MEASURED


# --- the report -------------------------------------------------------------------------------

def test_cells_name_their_interval():
    assert tables.format_cell([97.25]) == "97.2 (1 seed)"
    assert tables.format_cell([97.0, 99.0, 98.0]) == "98.0 (97.0 to 99.0, 3 seeds)"
    five = tables.format_cell([90.0, 95.0, 100.0, 96.0, 94.0])
    assert five.startswith("95.0 [") and "seeds" not in five
    assert tables.format_cell([]) == ""


def test_report_marks_experts_that_do_not_count(tmp_path):
    cells = {**_simple(99.5), ("highway-fast-v0", "a2c", "imitation-bt"): 100.0,
             ("highway-fast-v0", "a2c", "bc"): 100.0}
    _write(tmp_path, "distillation", _grid(cells))
    _experts(tmp_path, {("highway-fast-v0", "a2c"): "constant-action"})
    res = stats.Results(tmp_path)
    block = markdown.results_markdown(res)  # the grid's table: paper/results.md
    assert "| highway-fast-v0 | a2c † |" in block
    assert "† highway-fast-v0 a2c: constant-action expert (evidence highway-fast-v0 a2c)" in block
    assert "95 % CI" not in block and "range, min to max" in block
    text = markdown.report_markdown(res)
    assert "| highway-fast-v0 | a2c † |" in text and "## Beyond the paper" in text
    assert "IQM" in text


def test_beyond_the_paper_reads_its_tables(tmp_path):
    res = stats.Results(tmp_path)
    assert beyond.beyond_markdown(res).count("_not measured") == len(beyond.BEYOND)
    _write(tmp_path, "synthesis", pd.DataFrame([
        {"task": "CartPole-v1", "expert": "dqn", "method": m, "seed": 0, "nodes": n}
        for m, n in [("imitation-bt", 20), ("decision-list", 10)]]))
    _write(tmp_path, "front", pd.DataFrame({"task": ["CartPole-v1"], "expert": ["dqn"],
                                            "method": ["imitation-bt+"], "seed": [0],
                                            "max_leaf_nodes": [3], "bt_nodes": [9],
                                            "retention_norm": [97.0]}))
    text = beyond.beyond_markdown(res)
    assert text.count("_not measured") == 3  # Imitation-BT+S's and +SR's tables are not there
    assert "front_protocol.csv" in text and "structure_ablation.csv" in text
    assert "relational_search.csv" in text
    _write(tmp_path, "structure_ablation", pd.DataFrame([
        {"task": "MountainCar-v0", "expert": "dqn", "max_leaf_nodes": 3, "seed": 0,
         "expert_help": helped, "bt_nodes": 6, "mean_return": r}
        for helped, r in [(True, -110.0), (False, -115.0)]]))
    text = beyond.beyond_markdown(res)
    assert "structure_ablation.csv" not in text
    assert "| MountainCar-v0 | dqn | 3 | 1 | -110.0 | 6.0 | -115.0 | 6.0 | +5.0 |" in text
    assert "| CartPole-v1 | dqn | 20.0 | 10.0 | 0.50 |" in text
    assert "| CartPole-v1 | imitation-bt+ | 9: 97.0 | 97.0 (9) |" in text


def _searched(nodes: list[int], returns: list[float]) -> pd.DataFrame:
    return pd.DataFrame([
        {"task": "LunarLander-v3", "expert": "ppo", "max_leaf_nodes": 10, "seed": s,
         "bt_nodes": n, "relational_tests": 2, "protocol_mean_return": r,
         "share_at_threshold": 0.8, "cpu_seconds": 600.0, "bar_max_bt_nodes": 25,
         "bar_min_return": 200.0, "bar_strict": False, "bar_min_share": None,
         "bar_source": "small-BT target", "bar_seeds": 3}
        for s, (n, r) in enumerate(zip(nodes, returns, strict=True))])


@pytest.mark.parametrize("nodes, returns, verdict", [
    ([21, 25, 23], [210.0, 195.0, 205.0], "met"),  # the mean over seeds meets the bar
    ([21, 26, 23], [210.0, 215.0, 205.0], "missed"),  # one seed's BT is too large
    ([21, 25, 23], [190.0, 195.0, 205.0], "missed"),  # the mean falls short
    ([21, 25], [210.0, 215.0], "missed"),  # too few seeds
])
def test_relational_search_verdicts_read_the_bar_in_the_table(tmp_path, nodes, returns, verdict):
    _write(tmp_path, "relational_search", _searched(nodes, returns))
    text = beyond.relational_search_markdown(stats.Results(tmp_path))
    row = next(line for line in text.splitlines() if line.startswith("| LunarLander-v3"))
    assert row.endswith(f"| {verdict} |")
    assert f"| budget trees | {len(nodes)} | {np.mean(nodes):.1f} ({max(nodes)}) |" in row


def test_relational_search_against_an_anchor_needs_more_than_its_mean_and_its_share(tmp_path):
    anchor = {"bar_max_bt_nodes": 45, "bar_min_return": 240.6, "bar_strict": True,
              "bar_min_share": 0.9, "bar_source": "MENS-DT-RL"}
    for returns, share, verdict in [([241.0] * 3, 0.92, "met"), ([240.6] * 3, 0.92, "missed"),
                                    ([245.0] * 3, 0.85, "missed")]:
        _write(tmp_path, "relational_search", _searched([40] * 3, returns).assign(
            share_at_threshold=share, **anchor))
        text = beyond.relational_search_markdown(stats.Results(tmp_path))
        row = next(line for line in text.splitlines() if line.startswith("| LunarLander-v3"))
        assert row.endswith(f"| {verdict} |") and "(MENS-DT-RL)" in row


def test_deviations_name_the_experts_networks_and_steps(tmp_path):
    _experts(tmp_path, {("CartPole-v1", "dqn"): "ok"})
    manifest = pd.read_csv(tmp_path / "experts" / "manifest.csv")
    manifest = pd.concat([manifest, manifest.assign(algo="ppo", net_arch="256x256",
                                                    timesteps=20_000)])
    manifest.to_csv(tmp_path / "experts" / "manifest.csv", index=False)
    text = deviations.deviations_markdown(stats.Results(tmp_path))
    assert "1 use 256x256 (CartPole PPO)" in text
    assert "1,000 to 20,000 steps" in text and "2,000,000" in text
    assert "highway-fast-v0 (10)" in text  # the iterations, from the task catalogue


def test_readme_blocks_replace_only_their_marked_section(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"# T\nbefore\n{markdown.README_BEGIN}\nold\n{markdown.README_END}\nmid\n"
                      f"{markdown.DEVIATIONS_BEGIN}\nold2\n{markdown.DEVIATIONS_END}\nafter\n")
    assert markdown.update_readme(readme, f"{markdown.README_BEGIN}\nnew\n{markdown.README_END}")
    assert markdown.update_readme(readme, markdown.deviations_block(stats.Results(tmp_path)),
                                markdown.DEVIATIONS_BEGIN, markdown.DEVIATIONS_END)
    text = readme.read_text()
    assert "new" in text and "old" not in text and text.endswith("after\n")
    assert "retention" in text and "paper/reproduction.md" in text  # points to the list
    unchanged = f"{markdown.README_BEGIN}\nnew\n{markdown.README_END}"
    assert not markdown.update_readme(readme, unchanged)
    (tmp_path / "bad.md").write_text("no markers")
    with pytest.raises(ValueError, match="markers"):
        markdown.update_readme(tmp_path / "bad.md", "x")


def test_timings_read_the_make_figures_record(tmp_path):
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "make_figures.json").write_text(
        json.dumps({"seconds": 123.4, "machine": "x86_64, 2 cores", "date": "2026-11-22"}))
    # the README and the paper name the record, never its time (it changes on every run) ...
    written = tables.timings_markdown(stats.Results(tmp_path))
    assert "123" not in written and "data/results/make_figures.json" in written
    # ... `make reproduce` prints the time itself
    assert "123 s" in tables.timings_markdown(stats.Results(tmp_path), with_record=True)


def test_node_claim_without_a_complete_counted_cell_is_not_measured(tmp_path):
    syn = _synthesis(12)
    syn = syn[~((syn.method == "bt-espresso") & (syn.task != "LunarLander-v3"))]
    _write(tmp_path, "synthesis", syn.assign(expert="a2c"))
    _experts(tmp_path, {("LunarLander-v3", "a2c"): "excluded"})
    claim = claims.claim_nodes(stats.Results(tmp_path))
    assert claim.verdict == NOT_MEASURED and "no counted cell" in claim.reason


def test_mountaincar_front_without_mountaincar_runs_is_not_measured(tmp_path):
    facts, front = _car(11)
    _qualitative(tmp_path, facts)
    _write(tmp_path, "bt_size_front", front.assign(task="CartPole-v1"))
    claim = claims.claim_mountaincar(stats.Results(tmp_path))
    assert claim.verdict == NOT_MEASURED and "no MountainCar runs" in claim.reason


def test_relational_search_keeps_runs_of_different_settings_apart(tmp_path):
    """Three seeds of the task's budget and three of a larger one are two rows, never one
    mean of six; a variant's setting is named."""
    base = _searched([21, 25, 23], [210.0, 195.0, 205.0]).assign(
        search_budget=24_000, candidate_weights="fixed")
    larger = _searched([21, 25, 23], [150.0, 155.0, 160.0]).assign(
        search_budget=40_000, candidate_weights="scaled to spreads")
    _write(tmp_path, "relational_search", pd.concat([base, larger], ignore_index=True))
    text = beyond.relational_search_markdown(stats.Results(tmp_path))
    rows = [line for line in text.splitlines() if line.startswith("| LunarLander-v3")]
    assert len(rows) == 2
    assert "| budget trees; 24,000 search episodes | 3 |" in rows[0]
    assert rows[0].endswith("| met |")
    assert ("| budget trees; 40,000 search episodes; weights scaled to spreads | 3 |"
            in rows[1]) and rows[1].endswith("| missed |")


def test_relational_search_keeps_leaf_rules_apart(tmp_path):
    """The same seeds and budget with leaf actions by the expert's votes and by its scores
    are two runs: two rows, the variant named."""
    vote = _searched([21, 25, 23], [210.0, 195.0, 205.0]).assign(leaf_rule="vote")
    score = _searched([21, 25, 23], [150.0, 155.0, 160.0]).assign(leaf_rule="score")
    _write(tmp_path, "relational_search", pd.concat([vote, score], ignore_index=True))
    text = beyond.relational_search_markdown(stats.Results(tmp_path))
    rows = [line for line in text.splitlines() if line.startswith("| LunarLander-v3")]
    assert len(rows) == 2 and "leaf actions" not in rows[0]
    assert "| budget trees; leaf actions by the expert's mean scores | 3 |" in rows[1]


def test_relational_search_names_a_longer_held_out_choice(tmp_path):
    """Runs chosen on more held-out episodes than the task's are another setting: their own
    row, named; the task's own choice (None) adds nothing to the name."""
    task = _searched([21, 25, 23], [210.0, 195.0, 205.0]).assign(selection_episodes=None)
    longer = _searched([21, 25, 23], [215.0, 200.0, 205.0]).assign(selection_episodes=500)
    _write(tmp_path, "relational_search", pd.concat([task, longer], ignore_index=True))
    text = beyond.relational_search_markdown(stats.Results(tmp_path))
    rows = [line for line in text.splitlines() if line.startswith("| LunarLander-v3")]
    assert len(rows) == 2 and "held-out" not in rows[0]
    assert "| budget trees; chosen on 500 held-out episodes | 3 |" in rows[1]
