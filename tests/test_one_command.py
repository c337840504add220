"""The one-command results: a command's draws (``<case>-seed<k>``) are summarised together, the
mean lies within its draws' range, text from the benchmark file is escaped, and the README's
block is the one the committed benchmark gives."""

from __future__ import annotations

import pandas as pd
from hypothesis import given
from hypothesis import strategies as st

from ibt.paths import DATA_DIR, ROOT
from ibt.pipeline.recommend import DEFAULT_TIME
from ibt.report.one_command import (
    BEGIN,
    END,
    SENTENCE_BEGIN,
    SENTENCE_END,
    one_command_block,
    one_command_draws,
    readme_sentence,
    small_tasks_markdown,
)
from ibt.runs.controllers import OURS


def _row(case: str, seed: float | None, mean: float, nodes: int = 20, commit: str = "",
         **fields) -> dict:
    return {"case": case, "task": "LunarLander-v3", "algo": "ppo", "time_limit": "30m",
            "leaves": "default", "max_nodes": None, "bt_nodes": float(nodes),
            "confirm_mean": mean, "confirm_episodes": 1000.0, "confirm_share_200": 0.9,
            "wall_s": 1800.0, "seed": seed, "commit": commit, "retention_confirmed": 99.0,
            "learner": "oblique", **fields}


def test_draws_of_one_command_are_one_row_and_unconfirmed_cases_none():
    bench = pd.DataFrame([
        _row("thermostat", 0.0, float("nan")),
        _row("lunarlander-ppo-seed2", 2.0, 250.0, nodes=18, commit="abc12345"),
        _row("lunarlander-ppo", None, 240.0, nodes=20),
        _row("lunarlander-ppo-22", None, 260.0, leaves="22", time_limit="60m"),
        _row("lunarlander-ppo-seed1", 1.0, 230.0, nodes=25, commit="abc12345"),
    ])
    draws = one_command_draws(bench)
    assert list(draws.case) == ["lunarlander-ppo", "lunarlander-ppo-22"]
    first = draws.iloc[0]
    assert first.seeds == "0, 1, 2" and first.draws == 3
    assert first.commits == "0: not recorded; 1: abc12345; 2: abc12345"
    assert (first.nodes_min, first.nodes_max) == (18, 25)
    assert first.mean_return == 240.0 and (first.lowest_return, first.highest_return) == (
        230.0, 250.0)
    assert first.options == "--time 30m"
    assert draws.iloc[1].options == "--leaves 22 --time 60m"


@given(st.lists(st.floats(-500, 500, allow_nan=False), min_size=1, max_size=6))
def test_the_mean_of_draws_lies_within_their_range(means):
    bench = pd.DataFrame([_row(f"lunarlander-dqn-seed{k}" if k else "lunarlander-dqn",
                               float(k), m) for k, m in enumerate(means)])
    row = one_command_draws(bench).iloc[0]
    assert row.draws == len(means)
    assert row.lowest_return - 1e-9 <= row.mean_return <= row.highest_return + 1e-9


def test_text_from_the_benchmark_file_is_escaped():
    bench = pd.DataFrame([_row("x", 0.0, 1.0, commit="<script>|", task="<b>Env|v0"),
                          _row("y", 0.0, float("nan"), time_limit="10m", learner="<i>")])
    block = one_command_block(bench, DEFAULT_TIME, OURS)
    assert "<script>" not in block and "<b>" not in block and "<i>" not in block
    assert "&lt;script&gt;\\|" in block and block.startswith(BEGIN) and block.endswith(END)


def test_small_tasks_are_the_default_time_and_count_the_steering_learners():
    bench = pd.DataFrame([_row("a", 0.0, float("nan"), time_limit="10m", learner="axis"),
                          _row("b", 0.0, float("nan"), time_limit="600s", learner="controller"),
                          _row("c", 0.0, float("nan"), time_limit="15m", learner="oblique"),
                          _row("d", 0.0, 250.0, time_limit="10m", learner="oblique")])
    text = small_tasks_markdown(bench, DEFAULT_TIME, OURS)
    assert text.count("| LunarLander-v3 ppo |") == 2  # a and b: 15m and confirmed left out
    assert "made 1 of these 2 BTs" in text


def test_the_guide_and_the_readme_say_what_the_committed_benchmark_gives():
    bench = pd.read_csv(DATA_DIR / "results" / "pipeline_bench.csv")
    guide = (ROOT / "docs" / "own-agent.md").read_text()
    assert one_command_block(bench, DEFAULT_TIME, OURS) in guide
    assert readme_sentence(one_command_draws(bench)) in (ROOT / "README.md").read_text()


def test_the_readme_quotes_only_commands_with_enough_draws():
    bench = pd.DataFrame([_row("lunarlander-ppo", 0.0, 240.0),
                          _row("lunarlander-ppo-seed1", 1.0, 250.0),
                          _row("lunarlander-ppo-seed2", 2.0, 230.0),
                          _row("lunarlander-dqn", 0.0, 215.0, algo="dqn")])
    text = " ".join(readme_sentence(one_command_draws(bench)).split())
    assert "`--time 30m` PPO 240.0 (230.0-250.0)" in text
    assert "LunarLander-v3, 3 draws of each command on 1,000 fresh episodes:" in text
    assert "DQN" not in text and "1 other command has fewer draws so far." in text
    assert text.startswith(SENTENCE_BEGIN) and text.endswith(SENTENCE_END)


def test_a_run_given_fewer_processes_than_cores_names_its_jobs():
    """A ``--time`` run's steps depend on the processes it had, so ``--jobs`` below the
    machine's cores is part of the command; draws that differ in it say both."""
    bench = pd.DataFrame([_row("lunarlander-dqn", 0.0, 215.0, jobs=1.0, cpus=2),
                          _row("lunarlander-dqn-seed1", 1.0, 225.0, jobs=1.0, cpus=2),
                          _row("lunarlander-ppo", 0.0, 240.0, jobs=2.0, cpus=2),
                          _row("lunarlander-ppo-seed1", 1.0, 250.0, jobs=1.0, cpus=2)])
    draws = one_command_draws(bench)
    assert list(draws.options) == ["--time 30m --jobs 1", "--time 30m or --time 30m --jobs 1"]
