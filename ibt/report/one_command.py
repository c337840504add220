"""The one-command results of the pipeline's benchmark (``data/results/pipeline_bench.csv``):
the small tasks run at the default time (wall time, BT, retention, the learner that made it),
and each command confirmed on fresh episodes (the LunarLander rows), its draws (``--seed``)
summarised as the mean and range of the recommended BT's return, its sizes and wall times.

A ``--time`` run's steps depend on the machine's speed and load, so its draws differ by seed
and by machine; the code each draw measured (its commit, where the benchmark recorded one) is
listed beside it, since draws of different code are not draws of one command.
"""

from __future__ import annotations

import re
from typing import Any

import pandas as pd

from ibt.report.text import md

_DRAW = re.compile(r"-seed\d+$")
BEGIN = "<!-- one-command:begin (written by notebooks/09_report.ipynb) -->"
END = "<!-- one-command:end -->"
#: the README's sentence of the same results (inside a list item)
SENTENCE_BEGIN = "<!-- one-command-sentence:begin (written by notebooks/09_report.ipynb) -->"
SENTENCE_END = "<!-- one-command-sentence:end -->"
DRAWS = 3  #: draws of a command before the README quotes its mean and range


def options_of(row: Any) -> str:
    """The benchmarked command's options beyond the task and the agent (``--leaves``,
    ``--max-nodes``, ``--time``, and ``--jobs`` where the run had fewer processes than the
    machine's cores: a ``--time`` run's steps depend on the processes it had)."""
    parts = []
    if str(row.leaves) not in ("default", "", "nan"):
        parts.append(f"--leaves {row.leaves}")
    if pd.notna(row.max_nodes) and str(row.max_nodes) != "":
        parts.append(f"--max-nodes {int(float(row.max_nodes))}")
    parts.append(f"--time {row.time_limit}")
    jobs: Any = getattr(row, "jobs", None)
    cpus: Any = getattr(row, "cpus", None)
    if pd.notna(jobs) and pd.notna(cpus) and int(float(jobs)) < int(float(cpus)):
        parts.append(f"--jobs {int(float(jobs))}")
    return " ".join(parts)


def one_command_draws(bench: pd.DataFrame) -> pd.DataFrame:
    """One row per confirmed command (cases named ``<case>-seed<k>`` are draws of ``<case>``),
    in the benchmark's order: its seeds, the commits they measured, the BT's nodes and
    confirmed return (mean of the draws, lowest, highest), the share of episodes >= 200 and
    the wall times."""
    confirmed = bench[pd.to_numeric(bench.confirm_mean, errors="coerce").notna()].copy()
    if confirmed.empty:
        return pd.DataFrame(columns=COLUMNS)
    confirmed["command_case"] = confirmed.case.str.replace(_DRAW, "", regex=True)
    confirmed["draw_seed"] = pd.to_numeric(confirmed.seed, errors="coerce").fillna(0).astype(int)
    rows = []
    for case, draws in confirmed.groupby("command_case", sort=False):
        draws = draws.sort_values("draw_seed")
        means = draws.confirm_mean.astype(float)
        commits = draws.commit.fillna("").astype(str).replace("", "not recorded")
        rows.append({
            "case": case, "task": draws.task.iloc[0], "algo": draws.algo.iloc[0],
            "options": " or ".join(dict.fromkeys(options_of(d) for d in draws.itertuples())),
            "seeds": ", ".join(str(s) for s in draws.draw_seed),
            "commits": "; ".join(f"{s}: {c}" for s, c in zip(draws.draw_seed, commits,
                                                              strict=True)),
            "draws": len(draws), "episodes": int(draws.confirm_episodes.astype(float).min()),
            "nodes_min": int(draws.bt_nodes.astype(float).min()),
            "nodes_max": int(draws.bt_nodes.astype(float).max()),
            "mean_return": float(means.mean()), "lowest_return": float(means.min()),
            "highest_return": float(means.max()),
            "share_200": float(draws.confirm_share_200.astype(float).mean()),
            "wall_min_s": float(draws.wall_s.astype(float).min()),
            "wall_max_s": float(draws.wall_s.astype(float).max())})
    return pd.DataFrame(rows, columns=COLUMNS)


COLUMNS = ["case", "task", "algo", "options", "seeds", "commits", "draws", "episodes", "nodes_min",
           "nodes_max", "mean_return", "lowest_return", "highest_return", "share_200",
           "wall_min_s", "wall_max_s"]


def _span(low: float, high: float, fmt: str) -> str:
    return format(low, fmt) if format(low, fmt) == format(high, fmt) else (
        f"{format(low, fmt)}-{format(high, fmt)}")


def one_command_markdown(draws: pd.DataFrame) -> str:
    """The table of :func:`one_command_draws`, for the guide (``docs/own-agent.md``)."""
    lines = ["| task, agent | options | draws (`--seed`) | code measured (seed: commit) | "
             "BT nodes | fresh episodes a draw | return: mean of draws (lowest-highest) | "
             "episodes >= 200 (mean) | wall time, 2 cores |",
             "|---|---|---|---|---|---|---|---|---|"]
    for row in draws.itertuples():
        spread = (f"{row.mean_return:.1f} ({row.lowest_return:.1f}-{row.highest_return:.1f})"
                  if row.draws > 1 else f"{row.mean_return:.1f} (one draw)")
        wall = _span(row.wall_min_s / 60, row.wall_max_s / 60, ".0f")
        lines.append(f"| {md(row.task)} {md(row.algo)} | {md(row.options)} | {row.draws} "
                     f"({row.seeds}) | {md(row.commits)} | "
                     f"{_span(row.nodes_min, row.nodes_max, 'd')} | {row.episodes:,} | {spread} "
                     f"| {100 * row.share_200:.1f} % | {wall} min |")
    return "\n".join(lines)


def small_tasks(bench: pd.DataFrame, default_time: float) -> pd.DataFrame:
    """The cases run at the pipeline's default time (``default_time`` seconds) and not
    confirmed further: the small tasks a user meets first."""
    confirmed = pd.to_numeric(bench.confirm_mean, errors="coerce").notna()
    seconds = bench.time_limit.astype(str).map(lambda label: pd.to_timedelta(label).total_seconds())
    return bench[(seconds == default_time) & ~confirmed]


def small_tasks_markdown(bench: pd.DataFrame, default_time: float, steering: tuple[str, ...]
                         ) -> str:
    """The small tasks' table, and how many of their BTs the ``steering`` learners made."""
    rows = small_tasks(bench, default_time)
    lines = ["| task, agent | wall time, 2 cores | BT nodes | retention (held-out episodes) | "
             "learner of the BT |", "|---|---|---|---|---|"]
    for row in rows.itertuples():
        lines.append(f"| {md(row.task)} {md(row.algo)} | {float(row.wall_s):.0f} s | "
                     f"{int(float(row.bt_nodes))} | {float(row.retention_confirmed):.1f} % | "
                     f"{md(row.learner)} |")
    made = int(rows.learner.isin(steering).sum())
    names = " and ".join(f"`{md(name)}`" for name in sorted(steering))
    return "\n".join([*lines, "", f"The learners that steer ({names}: linear commands, "
                       f"tests over up to four features) made {made} of these {len(rows)} "
                       "BTs."])


def one_command_block(bench: pd.DataFrame, default_time: float, steering: tuple[str, ...]
                      ) -> str:
    """The guide's block, :data:`BEGIN` and :data:`END` included (``default_time``: the
    pipeline's, in seconds; ``steering``: the learners of linear commands and oblique tests)."""
    return "\n".join([BEGIN, "", small_tasks_markdown(bench, default_time, steering), "",
                       one_command_markdown(one_command_draws(bench)), "", END])


def readme_sentence(draws: pd.DataFrame) -> str:
    """The README's sentence between :data:`SENTENCE_BEGIN` and :data:`SENTENCE_END`: the mean
    and range of each command with :data:`DRAWS` draws or more, and how many have fewer."""
    import textwrap

    full = draws[draws.draws >= DRAWS]
    said = []
    for (task, counts, episodes), by_task in full.groupby(
            ["task", "draws", "episodes"], sort=False):
        commands = "; ".join(
            f"`{md(options)}` " + ", ".join(f"{md(row.algo).upper()} {row.mean_return:.1f} "
                                            f"({row.lowest_return:.1f}-"
                                            f"{row.highest_return:.1f})"
                                            for row in group.itertuples())
            for options, group in by_task.groupby("options", sort=False))
        said.append(f"{md(task)}, {counts} draws of each command on {int(episodes):,} fresh "
                    f"episodes: {commands}")
    fewer = len(draws) - len(full)
    others = f"{fewer} other command has" if fewer == 1 else f"{fewer} other commands have"
    text = "; ".join(said) + (f"; {others} fewer draws so far" if fewer else "") + "."
    body = textwrap.fill(text, width=98, initial_indent="  ", subsequent_indent="  ",
                         break_on_hyphens=False)
    return "\n".join([SENTENCE_BEGIN, body + SENTENCE_END])
