"""The reproduction report and the README's generated blocks, as markdown.

Everything here is formatting: the numbers come from :mod:`ibt.report.stats` (intervals,
aggregates) and the verdicts from :mod:`ibt.report.claims`, both reading the committed tables
only (``data/results/*.csv``, their manifests, ``data/experts/manifest.csv``), so the report is
regenerated in seconds and cannot drift from the CSVs. The budgets of the distillation come from
the task catalogue (:mod:`ibt.tasks.builtin`, code, not a result) for the list of deviations
from the paper.

Cells of a table print ``mean [a, b]`` when ``[a, b]`` is a 95 % percentile bootstrap CI (5 or
more seeds) and ``mean (a to b, n seeds)`` when it is the range of fewer seeds. Experts whose
status is not ``ok`` are marked (:data:`STATUS_MARKS`) and explained in a footnote.

"Beyond the paper" (:data:`BEYOND`) collects results the paper does not have; each part reads
its own table and says "not measured" while it is absent. To add one, append a
:class:`BeyondPart` whose ``render`` returns markdown, or ``None`` when its input is missing.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ibt.report.claims import NOT_MEASURED, SIMPLE_TASKS, STOCHASTIC_TASKS, TREE_METHODS, claims
from ibt.report.stats import (
    MIN_SEEDS_FOR_CI,
    Results,
    aggregate,
    counted,
    interval,
    node_table,
    retention_table,
    with_expert_status,
)

METHODS = (*TREE_METHODS, "bt-espresso", "re-bt-espresso")
README_BEGIN = "<!-- results:begin (written by notebooks/09_report.ipynb) -->"
README_END = "<!-- results:end -->"
DEVIATIONS_BEGIN = "<!-- deviations:begin (written by notebooks/09_report.ipynb) -->"
DEVIATIONS_END = "<!-- deviations:end -->"
STATUS_MARKS = {"excluded": "‡", "constant-action": "†"}
INTERVAL_LEGEND = (f"Each cell is the mean over seeds: `m [a, b]` gives the 95 % percentile "
                   f"bootstrap CI of the mean (cells with {MIN_SEEDS_FOR_CI} or more seeds), "
                   f"`m (a to b, n seeds)` the range, min to max, of fewer seeds (not a "
                   f"confidence interval).")
#: The paper's setup (Section IV.C, Implementation Details), against which deviations are listed
PAPER_NET = "64x64"
PAPER_TIMESTEPS = 2_000_000
PAPER_ITERATIONS = 50


def _fmt(x: float | None, digits: int = 1) -> str:
    return "n/a" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{x:.{digits}f}"


def format_cell(values: Sequence[float]) -> str:
    """``m [a, b]`` (bootstrap CI) or ``m (a to b, n seeds)`` (range); see the legend."""
    iv = interval(np.asarray(values, dtype=float))
    if iv.n == 0:
        return ""
    if iv.n == 1:
        return f"{iv.mean:.1f} (1 seed)"
    if iv.kind == "ci":
        return f"{iv.mean:.1f} [{iv.low:.1f}, {iv.high:.1f}]"
    return f"{iv.mean:.1f} ({iv.low:.1f} to {iv.high:.1f}, {iv.n} seeds)"


def _expert_label(expert: str, status: str) -> str:
    mark = STATUS_MARKS.get(status, "")
    return f"{expert} {mark}" if mark else expert


def status_footnotes(res: Results, shown: pd.DataFrame | None = None) -> str:
    """One line per expert that is not ``ok`` (among ``shown``'s task/expert pairs)."""
    lines = []
    pairs = None if shown is None else set(zip(shown["task"], shown["expert"], strict=True))
    for (task, algo), (status, evidence) in sorted(res.expert_status().items()):
        if status == "ok" or (pairs is not None and (task, algo) not in pairs):
            continue
        what = "excluded" if status == "excluded" else "constant-action expert"
        lines.append(f"{STATUS_MARKS.get(status, '')} {task} {algo}: {what} ({evidence}); "
                     "its cells stay in the tables and count in no claim.")
    return "\n".join(f"- {line}" for line in lines)


def _grid(res: Results) -> pd.DataFrame | None:
    grid = res.table("distillation")
    if grid is None or not {"task", "expert", "method", "retention_norm"} <= set(grid.columns):
        return None
    return with_expert_status(grid, res.expert_status())


def retention_markdown(res: Results, value: str = "retention_norm") -> str:
    """Task x expert rows, one column per method, each cell with its interval."""
    grid = _grid(res)
    if grid is None or value not in grid:
        return "_not measured: no distillation results_"
    syn = res.table("synthesis")
    rows = with_expert_status(retention_table(grid, syn), res.expert_status())
    present = [m for m in METHODS if m in set(rows.method)]
    lines = ["| task | expert | " + " | ".join(present) + " |",
             "|---|---|" + "---|" * len(present)]
    for (task, expert), part in rows.groupby(["task", "expert"], sort=False):
        cells = [format_cell(part[part.method == m][value].dropna().to_numpy()) for m in present]
        label = _expert_label(expert, part.expert_status.iloc[0])
        lines.append(f"| {task} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def nodes_markdown(res: Results) -> str:
    """Mean node counts: trees for BC/DAgger/VIPER, BTs for the synthesis methods."""
    grid, syn = _grid(res), res.table("synthesis")
    if grid is None or syn is None or "nodes" not in grid or "nodes" not in syn:
        return "_not measured: no distillation or synthesis results_"
    syn = with_expert_status(syn, res.expert_status())
    counts = node_table(grid, syn)
    table = counts.pivot_table(index=["task", "expert"], columns="method", values="nodes",
                               aggfunc="mean", sort=False)
    status = res.expert_status()
    present = [m for m in (*METHODS, "decision-list") if m in table.columns]
    lines = ["| task | expert | " + " | ".join(present) + " |",
             "|---|---|" + "---|" * len(present)]
    for (task, expert), row in table.iterrows():
        label = _expert_label(expert, status.get((task, expert), ("ok", ""))[0])
        lines.append(f"| {task} | {label} | " + " | ".join(_fmt(row[m], 1) for m in present)
                     + " |")
    return "\n".join(lines)


def headline_markdown(res: Results) -> str:
    """The README's headline: Imitation-BT vs BC retention and BT size vs RE:BT per task."""
    grid = _grid(res)
    if grid is None:
        return "_not measured: no distillation results_"
    syn = res.table("synthesis")
    lines = ["| task | expert | expert return | BC retention | Imitation-BT retention | "
             "Imitation-BT nodes | RE:BT-Espresso nodes |", "|---|---|---|---|---|---|---|"]
    for (task, expert), part in grid.groupby(["task", "expert"], sort=False):
        ours, bc = part[part.method == "imitation-bt"], part[part.method == "bc"]
        nodes: tuple[str, ...] = ("", "")
        if syn is not None and {"task", "expert", "method", "nodes"} <= set(syn.columns):
            s = syn[(syn.task == task) & (syn.expert == expert)]
            nodes = tuple(_fmt(s[s.method == m].nodes.mean(), 0) if (s.method == m).any()
                          else "" for m in ("imitation-bt", "re-bt-espresso"))
        expert_return = (_fmt(float(part.expert_return.iloc[0]))
                         if "expert_return" in part else "")
        lines.append(f"| {task} | {_expert_label(expert, part.expert_status.iloc[0])} | "
                     f"{expert_return} | {format_cell(bc.retention_norm.to_numpy())} | "
                     f"{format_cell(ours.retention_norm.to_numpy())} | {nodes[0]} | "
                     f"{nodes[1]} |")
    return "\n".join(lines)


def aggregate_markdown(res: Results) -> str:
    """IQM retention per method over the counted cells of each task group, stratified CI."""
    grid = _grid(res)
    if grid is None:
        return "_not measured: no distillation results_"
    rows = counted(with_expert_status(retention_table(grid, res.table("synthesis")),
                                      res.expert_status()))
    lines = ["| tasks | method | cells | runs | IQM retention_norm [95 % CI] |",
             "|---|---|---|---|---|"]
    for label, tasks in (("simpler", SIMPLE_TASKS), ("stochastic", STOCHASTIC_TASKS)):
        part = rows[rows.task.isin(tasks)]
        if part.empty:
            lines.append(f"| {label} | | | | not measured |")
            continue
        agg = aggregate(part).set_index("method")
        for m in [m for m in METHODS if m in agg.index]:
            a = agg.loc[m]
            lines.append(f"| {label} | {m} | {int(a.cells)} | {int(a.runs)} | {a.iqm:.1f} "
                         f"[{a.iqm_low:.1f}, {a.iqm_high:.1f}] |")
    return "\n".join(lines)


def experts_markdown(res: Results) -> str:
    """The experts: network, steps, return, bar, status."""
    experts = res.experts()
    if experts is None:
        return "_not measured: no experts' manifest_"
    lines = ["| task | expert | network | steps | mean return (100 episodes) | bar met | status |",
             "|---|---|---|---|---|---|---|"]
    for r in experts.itertuples():
        status = getattr(r, "status", "ok")
        status = status if isinstance(status, str) and status else "ok"
        lines.append(f"| {r.task} | {r.algo} | {r.net_arch} | {int(r.timesteps):,} | "
                     f"{r.mean_return:.1f} | {'yes' if bool(r.meets_bar) else 'no'} | "
                     f"{_expert_label(status, status)} |")
    return "\n".join(lines)


def timings_markdown(res: Results, with_record: bool = False) -> str:
    """How long each stage took (summed over its runs) and where.

    ``make figures``'s own wall time changes on every run, so the README and the paper (which
    ``make figures`` writes) only name its record, ``data/results/make_figures.json``;
    ``with_record`` prints the time itself (``make reproduce``'s estimate)."""
    lines = ["| stage | runs | CPU time (summed) | notes |", "|---|---|---|---|"]
    experts = res.experts()
    if experts is not None:
        lines.append(f"| training the experts | {len(experts)} | "
                     f"{experts.wall_seconds.sum() / 3600:.1f} h | "
                     f"{int(experts.timesteps.sum()):,} environment steps |")
    for name, label in [("distillation", "distillation grid (Fig. 4)"),
                        ("beta_analysis", "beta analysis (Fig. 3)"),
                        ("size_sweep", "tree-size sweep")]:
        table = res.table(name)
        if table is None:
            continue
        seconds = table.get("wall_seconds", pd.Series([0.0])).sum()
        lines.append(f"| {label} | {len(table)} | {seconds / 3600:.1f} h | "
                     f"machine: {res.manifest(name).get('machine', '?')} |")
    figures = res.results_dir / "make_figures.json"
    if figures.exists() and with_record:
        facts = json.loads(figures.read_text())
        lines.append(f"| `make figures`, last run (venv ready) | 1 | "
                     f"{facts['seconds']:.0f} s wall | "
                     f"{facts.get('machine', '')}, {facts.get('date', '')} |")
    elif figures.exists():  # a number here would change this file on every run
        lines.append("| `make figures` (venv ready) | 1 | wall time of the last run: "
                     "`data/results/make_figures.json` | written at the end of each run |")
    return "\n".join(lines)


def claims_markdown(frame: pd.DataFrame) -> str:
    lines = ["| claim | verdict | measured |", "|---|---|---|"]
    for row in frame.itertuples():
        lines.append(f"| {row.claim} | **{row.verdict}** | {row.measured} |")
    return "\n".join(lines)


# --- deviations from the paper's setup --------------------------------------------------------

def _names(rows: pd.DataFrame) -> str:
    return ", ".join(f"{t.split('-')[0]} {a.upper()}" for t, a in zip(rows.task, rows.algo,
                                                                       strict=True))


def deviations_markdown(res: Results) -> str:
    """Every way our setup differs from the paper's, with our numbers from the artifacts."""
    from ibt.tasks.builtin import BUILTIN, CLIFFWALKING, FROZENLAKE

    budgets = {task.name: task.budget for task in BUILTIN}

    items = []
    experts = res.experts()
    if experts is not None:
        nets = experts.net_arch.astype(str)
        big = experts[nets != PAPER_NET]
        items.append(f"**Expert networks.** The paper trains every agent with two hidden layers "
                     f"of 64 units; {len(experts) - len(big)} of our {len(experts)} experts use "
                     f"that, {len(big)} use {', '.join(sorted(set(big.net_arch.astype(str))))} "
                     f"({_names(big)}), because 2x64 missed the quality bar or the "
                     "hyperparameter source uses the larger network.")
        steps = experts.timesteps.astype(int)
        items.append(f"**Expert training.** The paper trains every agent for "
                     f"{PAPER_TIMESTEPS:,} steps with Stable-Baselines3's default "
                     f"hyperparameters; ours train for {steps.min():,} to {steps.max():,} steps "
                     f"({int((steps < PAPER_TIMESTEPS).sum())} of {len(steps)} fewer than "
                     f"{PAPER_TIMESTEPS:,}; {_names(experts[steps == steps.min()])} the fewest) "
                     "with tuned hyperparameters: "
                     + ", ".join(f"{n} tuned here" if src == "ours" else f"{n} from {src}"
                                 for src, n in experts.hyperparams_source.astype(str)
                                 .str.split(" ").str[0].value_counts().items())
                     + " (the task catalogue, `ibt/tasks/builtin.py`; "
                     "`data/experts/manifest.csv`). "
                     "The paper's "
                     "experts are not public; a stronger or weaker expert moves every retention "
                     "number.")
        bad = experts[experts.get("status", pd.Series("ok", index=experts.index))
                      .fillna("ok") != "ok"]
        if len(bad):
            items.append("**Experts left out of the claims.** "
                         + "; ".join(f"{r.task} {r.algo.upper()}: {r.status} "
                                     f"({r.status_evidence})" for r in bad.itertuples())
                         + ". Their cells stay in the tables, marked.")
    slow = {t: b.max_iterations for t, b in budgets.items() if b.max_iterations}
    items.append(f"**Iterations.** The paper runs {PAPER_ITERATIONS} interactive iterations; so "
                 "do we, except " + ", ".join(f"{t} ({n})" for t, n in slow.items())
                 + ", whose simulator is too slow for 50 (see the README's method section).")
    items.append("**Label budgets and tree sizes** are not given in the paper; ours, per task "
                 "(labels per iteration / max leaves): "
                 + ", ".join(f"{t} {b.labels_per_iteration} / {b.max_leaf_nodes}"
                             for t, b in budgets.items())
                 + " (the task catalogue, `ibt/tasks/builtin.py`). Two were set after seeing "
                 "results: "
                 "CartPole's leaf limit (8 to 12, from the size sweep, on the same seeds) and "
                 "PackageDelivery's selection episodes (20 to 100, after a lucky tree won).")
    scaled = {t: b.selection_scale for t, b in budgets.items() if b.selection_scale > 1}
    items.append("**Best-tree selection and evaluation.** The paper keeps \"the best performing "
                 "DT\" without saying how it is scored; we pick the highest mean return on 20 "
                 "held-out episodes (" + ", ".join(f"{20 * s} on {t}" for t, s in scaled.items())
                 + ") and report 100 fixed final episodes, disjoint from training and "
                 "selection.")
    grid = res.table("distillation")
    if grid is not None and {"task", "expert", "method", "seed"} <= set(grid.columns):
        seeds = grid.groupby(["task", "expert", "method"]).seed.nunique()
        per_task = seeds.groupby(level="task").agg(["min", "max"])
        text = ", ".join(f"{t} {lo}" + (f"-{hi}" if hi != lo else "")
                         for t, (lo, hi) in per_task.iterrows())
        items.append(f"**Seeds.** The paper does not say how many runs each bar averages; ours "
                     f"average {text} seeds per cell. Intervals are named for what they are: "
                     f"the range of fewer than {MIN_SEEDS_FOR_CI} seeds, a 95 % bootstrap CI "
                     "from 5 on.")
    items.append("**Retention.** The paper divides returns (R / R_expert), which is meaningless "
                 "for negative returns (MountainCar, Acrobot, CliffWalking); we lead with the "
                 "random-normalised retention (R - R_random) / (R_expert - R_random) and report "
                 "both.")
    lake, cliff = FROZENLAKE, CLIFFWALKING
    items.append("**Environments.** Gymnasium 1.4's versions: LunarLander-v3 and CliffWalking-v1 "
                 f"(the paper used OpenAI Gym's), CliffWalking capped at "
                 f"{cliff.max_episode_steps} steps, FrozenLake 4x4 with is_slippery="
                 f"{lake.env_kwargs.get('is_slippery')} (the paper's two deterministic shortest "
                 "paths imply it), and highway-env's highway-fast-v0 for the paper's "
                 "unnamed \"Highway\". The package-delivery domain is our own implementation "
                 "of the paper's description (its simulation is not public): rewards, battery "
                 "costs and spawn rates are ours (`ibt/envs/package_delivery.py`).")
    items.append("**Baselines.** BT-Espresso and RE:BT-Espresso are rebuilt from their papers "
                 "and fed the BC tree of the same grid (offline demonstrations, as in their "
                 "papers); the BTs they produce decide exactly as that tree (verified), so their "
                 "retention is the BC tree's. The paper's DAgger schedule p is not given; ours "
                 "is 0.5, and our BC aggregates expert-only rollouts with the same label budget "
                 "as the interactive methods.")
    return "\n".join(f"- {item}" for item in items)


# --- beyond the paper -------------------------------------------------------------------------

@dataclass(frozen=True)
class BeyondPart:
    """One result the paper does not have: a title, its table, and how to render it."""

    title: str
    source: str  # the table it reads, under data/results/
    render: Callable[[Results], str | None]  # None: its input is absent


FRONT_BAR = 90.0  # % retention: "how small can a BT be and still keep this much of the expert"


def plus_targets_markdown(res: Results) -> str | None:
    """Imitation-BT+ against its targets (``front_targets.csv``), or None when absent."""
    targets = res.table("front_targets")
    if targets is None or targets.empty:
        return None
    lines = ["| task | expert | target | leaf limit | seeds | retention | BT nodes | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for r in targets.itertuples():
        measured = getattr(r, "verdict", NOT_MEASURED) != NOT_MEASURED
        retention = f"{r.retention_norm:.1f} ({r.retention_min:.1f})" if measured else "n/a"
        nodes = f"{r.bt_nodes:.1f}" if measured else "n/a"
        lines.append(f"| {r.task} | {r.expert} | {r.target} | {r.leaf_limit} | {r.seeds} "
                     f"| {retention} | {nodes} | {r.verdict} |")
    return "\n".join(lines)


def _front(res: Results) -> str | None:
    """Imitation-BT+ against its targets, and per method the smallest BT that keeps
    :data:`FRONT_BAR` % of the expert (notebook 07; the sweep expert's runs)."""
    targets, front = plus_targets_markdown(res), res.table("front")
    if targets is None and (front is None or front.empty):
        return None
    lines: list[str] = []
    if targets is not None:
        lines += ["Imitation-BT+ (the grid's best trees by their held-out selection score, "
                  "refined by return to a leaf limit, then the smallest verified BT) against "
                  "the targets set for it: mean over seeds (lowest seed in brackets) at the "
                  "task's headline leaf limit.", "", targets, ""]
    if front is not None and not front.empty:
        expert = front["expert"].mode().iloc[0]
        rows = front[front["expert"] == expert]
        means = rows.groupby(["task", "method", "max_leaf_nodes"], sort=False)[
            ["bt_nodes", "retention_norm"]].mean().reset_index()
        lines += [f"The front ({expert.upper()} expert, mean over seeds per leaf limit): the "
                  f"smallest BT whose method keeps at least {FRONT_BAR:.0f} % of the expert, "
                  "and the best retention at any limit.", "",
                  f"| task | method | smallest BT >= {FRONT_BAR:.0f} % (nodes: retention) | "
                  "best retention (nodes) |", "|---|---|---|---|"]
        for (task, method), group in means.groupby(["task", "method"], sort=False):
            good = group[group["retention_norm"] >= FRONT_BAR].sort_values("bt_nodes")
            best = group.sort_values("retention_norm").iloc[-1]
            small = (f"{good.iloc[0].bt_nodes:.0f}: {good.iloc[0].retention_norm:.1f}"
                     if not good.empty else "none")
            lines.append(f"| {task} | {method} | {small} | {best.retention_norm:.1f} "
                         f"({best.bt_nodes:.0f}) |")
    return "\n".join(lines)


def _decision_list(res: Results) -> str | None:
    syn = res.table("synthesis")
    if syn is None or "method" not in syn or not (syn.method == "decision-list").any():
        return None
    part = syn[syn.method.isin(["imitation-bt", "decision-list"])]
    nodes = part.pivot_table(index=["task", "expert"], columns="method", values="nodes",
                             aggfunc="mean", sort=False).dropna()
    lines = ["| task | expert | Imitation-BT nodes | decision-list nodes | ratio |",
             "|---|---|---|---|---|"]
    for (task, expert), row in nodes.iterrows():
        lines.append(f"| {task} | {expert} | {row['imitation-bt']:.1f} | "
                     f"{row['decision-list']:.1f} | "
                     f"{row['decision-list'] / row['imitation-bt']:.2f} |")
    return "\n".join(lines)


def _bar_verdict(g: pd.DataFrame, mean: float, share: float | None) -> tuple[str, str]:
    """The bar a group of seeds is judged against (its rows' ``bar_*`` columns, written by the
    run that made them) and the verdict: "met" when at least ``bar_seeds`` seeds ran, every
    seed's BT has at most ``bar_max_bt_nodes`` nodes, the mean return is at least (above, when
    ``bar_strict``) ``bar_min_return`` and the mean share at least ``bar_min_share``; "none"
    and "measured" where the rows carry no bar."""
    first = g.iloc[0]
    if pd.isna(first.get("bar_max_bt_nodes")):
        return "none", "measured"
    strict = bool(first.get("bar_strict", False))
    need_share = first.get("bar_min_share")
    bar = (f"{'>' if strict else '>='} {first['bar_min_return']:g} over >= "
           f"{int(first['bar_seeds'])} seeds, every BT <= {int(first['bar_max_bt_nodes'])} nodes"
           + (f", >= {100 * need_share:.0f} % >= threshold" if pd.notna(need_share) else "")
           + (f" ({first['bar_source']})" if isinstance(first.get("bar_source"), str) else ""))
    met = (len(g) >= first["bar_seeds"] and g["bt_nodes"].max() <= first["bar_max_bt_nodes"]
           and (mean > first["bar_min_return"] if strict else mean >= first["bar_min_return"])
           and (pd.isna(need_share) or (share is not None and share >= need_share)))
    return bar, "met" if met else "missed"


def structure_markdown(res: Results) -> str | None:
    """Imitation-BT+S on the anchors' protocol (``front_protocol.csv``): per task, expert and
    leaf limit, means over seeds of the committed BTs' 1,000-episode evaluation, against the
    bar written in the table (``bar_*`` columns, :func:`_bar_verdict`); None when absent."""
    rows = res.table("front_protocol")
    if rows is None or rows.empty:
        return None
    lines = ["| task | expert | leaf limit | seeds | leaves | BT nodes (max) | mean return (1,000 "
             "episodes) | std | share >= threshold | CPU-min a run | steps/s (random's) "
             "| bar | verdict |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    keys = ["task", "expert", "max_leaf_nodes"]
    for key, g in rows.groupby(keys, sort=False):
        task, expert, limit = key
        share = g["share_at_threshold"].mean() if g["share_at_threshold"].notna().any() else None
        mean, nodes = g["mean_return"].mean(), g["bt_nodes"].mean()
        bar, verdict = _bar_verdict(g, mean, share)
        share_text = f"{100 * share:.1f} %" if share is not None else "n/a"
        speed = (f"{g['search_steps_per_second'].mean():,.0f} "
                 f"({g['random_steps_per_second'].mean():,.0f})")
        lines.append(f"| {task} | {expert} | {int(limit)} | {len(g)} | "
                     f"{g['tree_leaves'].mean():.1f} | {nodes:.1f} ({int(g['bt_nodes'].max())}) | "
                     f"{mean:.1f} | "
                     f"{g['std_return'].mean():.1f} | {share_text} | "
                     f"{g['cpu_seconds'].mean() / 60:.1f} | {speed} | {bar} | {verdict} |")
    return "\n".join(lines)


def _introduced(intro: str, table: str | None) -> str | None:
    """A beyond-the-paper part: its introduction, then its table (None when absent)."""
    return None if table is None else "\n".join([intro, "", table])


def _structure(res: Results) -> str | None:
    return _introduced(
        "Imitation-BT+S (notebook 07: structure search by return seeded with Imitation-BT+'s "
        "and the four grid trees, helped by the expert's labels on the states the small trees "
        "visit, then CMA-ES and pruning) on the published anchors' protocol: each seed's "
        "smallest verified BT rolled out from its JSON document on 1,000 final episodes; means "
        "over seeds. Each row's bar is written by its run: at 12 leaves or fewer on LunarLander, "
        "the small-BT target (gymnasium's solved score from a BT small enough to read whole); "
        "otherwise the best published small policy of the task (MENS-DT-RL, Costa et al. 2024) "
        "at its own size.", structure_markdown(res))


def ablation_markdown(res: Results) -> str | None:
    """The structure search with and without the expert's help (``structure_ablation.csv``):
    per task, expert and leaf limit, means over seeds of the polished trees' 100 final
    episodes and smallest verified BTs; None when absent."""
    rows = res.table("structure_ablation")
    if rows is None or rows.empty:
        return None
    lines = ["| task | expert | leaf limit | seeds | with the expert: mean return | BT nodes "
             "| reward alone: mean return | BT nodes | difference |",
             "|---|---|---|---|---|---|---|---|---|"]
    for (task, expert, limit), g in rows.groupby(["task", "expert", "max_leaf_nodes"],
                                                 sort=False):
        helped, alone = g[g["expert_help"]], g[~g["expert_help"]]
        lines.append(f"| {task} | {expert} | {int(limit)} | {len(helped)} | "
                     f"{helped['mean_return'].mean():.1f} | {helped['bt_nodes'].mean():.1f} | "
                     f"{alone['mean_return'].mean():.1f} | {alone['bt_nodes'].mean():.1f} | "
                     f"{helped['mean_return'].mean() - alone['mean_return'].mean():+.1f} |")
    return "\n".join(lines)


def _ablation(res: Results) -> str | None:
    return _introduced(
        "The same structure search on the same seed trees, budget and seeds, with the expert's "
        "labels (\"grow\" by a CART stump on them, \"relabel\" by their majority) and without "
        "(reward alone); each polished the same way and evaluated on 100 final episodes.",
        ablation_markdown(res))


def _search_setting(rows: pd.DataFrame) -> pd.Series:
    """What a run of Imitation-BT+SR was seeded with and, where recorded, its search budget,
    candidate weights, leaf rule and held-out choice (rows of different settings are different
    runs, never averaged)."""
    text = (rows["seeded_with"] if "seeded_with" in rows
            else pd.Series("budget trees", index=rows.index)).astype(str)
    if "search_budget" in rows:
        text = text + rows["search_budget"].map(
            lambda n: f"; {int(n):,} search episodes" if pd.notna(n) else "")
    if "candidate_weights" in rows:
        text = text + rows["candidate_weights"].map(
            lambda w: f"; weights {w}" if isinstance(w, str) and w != "fixed" else "")
    if "leaf_rule" in rows:
        text = text + rows["leaf_rule"].map(
            lambda r: "; leaf actions by the expert's mean scores" if r == "score" else "")
    if "selection_episodes" in rows:
        text = text + rows["selection_episodes"].map(
            lambda n: f"; chosen on {int(n):,} held-out episodes" if pd.notna(n) else "")
    return text


def relational_search_markdown(res: Results) -> str | None:
    """Imitation-BT+SR on the anchors' protocol (``relational_search.csv``): per task, expert
    and leaf limit, the committed BTs' 1,000-episode means over seeds against the bar written
    in the table (``bar_*``: every seed's BT at most so many nodes, the mean over at least so
    many seeds at least so much); None when absent."""
    rows = res.table("relational_search")
    if rows is None or rows.empty:
        return None
    rows = rows.assign(setting=_search_setting(rows))
    lines = ["| task | expert | leaf limit | seed trees and search | seeds | BT nodes (max) | "
             "relational tests | mean return (1,000 episodes) | worst seed | share >= threshold "
             "| CPU-min a run | bar | verdict |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for (task, expert, limit, seeded), g in rows.groupby(
            ["task", "expert", "max_leaf_nodes", "setting"], sort=False):
        mean, nodes = g["protocol_mean_return"].mean(), g["bt_nodes"]
        share = g["share_at_threshold"]
        bar, verdict = _bar_verdict(g, mean, share.mean() if share.notna().any() else None)
        share_text = f"{100 * share.mean():.1f} %" if share.notna().any() else "n/a"
        lines.append(f"| {task} | {expert} | {int(limit)} | {seeded} | {len(g)} | "
                     f"{nodes.mean():.1f} "
                     f"({int(nodes.max())}) | {g['relational_tests'].mean():.1f} | {mean:.1f} | "
                     f"{g['protocol_mean_return'].min():.1f} | {share_text} | "
                     f"{g['cpu_seconds'].mean() / 60:.1f} | {bar} | {verdict} |")
    return "\n".join(lines)


def _relational_search(res: Results) -> str | None:
    return _introduced(
        "Imitation-BT+SR (notebook 07): Imitation-BT+S's structure search, on the same seed "
        "trees, budget and polish, allowed to test `w1 * x_i + w2 * x_j <= t` for any pair of "
        "non-binary features and the relational learner's weight pairs; each seed's smallest "
        "verified BT rolled out from its JSON document on 1,000 final episodes. A relational "
        "test counts as one condition node.", relational_search_markdown(res))


BEYOND: list[BeyondPart] = [
    BeyondPart("Small BTs that keep the expert: Imitation-BT+ and the size-retention front",
               "front.csv", _front),
    BeyondPart("Imitation-BT+S: ahead of the published small trees at their own size?",
               "front_protocol.csv", _structure),
    BeyondPart("Imitation-BT+S: what the expert's help adds", "structure_ablation.csv",
               _ablation),
    BeyondPart("Relational tests: the structure search with conditions that compare features",
               "relational_search.csv", _relational_search),
    BeyondPart("Decision-list synthesis: nodes against Imitation-BT's", "synthesis.csv",
               _decision_list),
]


def beyond_markdown(res: Results) -> str:
    parts = []
    for part in BEYOND:
        body = part.render(res)
        parts += [f"### {part.title}", "",
                  body if body is not None else
                  f"_{NOT_MEASURED}: `data/results/{part.source}` has no such results yet._", ""]
    return "\n".join(parts)


# --- the documents ----------------------------------------------------------------------------

def report_markdown(res: Results) -> str:
    """The whole of ``paper/reproduction.md``."""
    table = claims(res)
    grid = _grid(res)
    parts = [
        "# Reproduction report",
        "",
        "Written by `notebooks/09_report.ipynb` from `data/results/` alone (regenerated by "
        "`make figures`). Retention is reported as `retention_norm` = (R - R_random) / "
        "(R_expert - R_random) x 100; the paper's raw definition (R / R_expert) is in the "
        "second table. " + INTERVAL_LEGEND + " Verdicts: **reproduced**, **partly**, **not "
        "reproduced**, or **not measured** when a result is not committed yet. Claims count only "
        "cells whose expert is `ok`: excluded (‡) and constant-action (†) experts stay in the "
        "tables and out of every verdict and count.",
        "",
        "## Claims",
        "",
        claims_markdown(table),
        "",
    ]
    for row in table.itertuples():
        parts += [f"### {row.claim}", "", f"- **Paper:** {row.paper}.",
                  f"- **Measured:** {row.measured}.",
                  f"- **Verdict:** {row.verdict}: {row.reason}."]
        if row.figure:
            parts += ["", f"![{row.claim}](../{row.figure})"]
        parts.append("")
    notes = status_footnotes(res, grid)
    parts += ["## Retention (normalised, %)", "", INTERVAL_LEGEND, "",
              retention_markdown(res), "", notes, "",
              "## Retention (the paper's raw definition, %)", "",
              retention_markdown(res, "retention_raw"), "",
              "## Retention across cells", "",
              "Interquartile mean (IQM) of `retention_norm` over every run of the counted cells "
              "(experts `ok` only), with a 95 % CI from a stratified bootstrap (runs resampled "
              "within their cell, 2,000 draws).", "",
              aggregate_markdown(res), "",
              "## Node counts (mean over seeds)", "",
              "Decision-tree nodes for BC, DAgger and VIPER; BT nodes (every node, as "
              "py_trees counts them) for the synthesis methods.", "",
              nodes_markdown(res), "", notes, "",
              "## The experts", "", experts_markdown(res), "", notes, "",
              "## How our setup differs from the paper's", "", deviations_markdown(res), "",
              "## Beyond the paper", "", beyond_markdown(res),
              "## How long each stage took", "", timings_markdown(res), ""]
    return "\n".join(parts)


def readme_block(res: Results) -> str:
    """The README's generated results section (between the markers)."""
    table = claims(res)
    grid = _grid(res)
    return "\n".join([
        README_BEGIN,
        "",
        "Imitation-BT against Behavior Cloning (random-normalised retention, %) and the size of "
        "the BTs (mean nodes over seeds). " + INTERVAL_LEGEND,
        "",
        headline_markdown(res),
        "",
        status_footnotes(res, grid),
        "",
        "The paper's claims, one line each, counting only `ok` experts (details in "
        "[paper/reproduction.md](paper/reproduction.md)):",
        "",
        "| claim | verdict | why |",
        "|---|---|---|",
        *[f"| {r.claim} | {r.verdict} | {r.reason} |" for r in table.itertuples()],
        "",
        *(["Beyond the paper: **Imitation-BT+** (notebook 07) refines the grid's best trees by "
           "return and keeps the smallest verified BT; mean over seeds (lowest seed in "
           "brackets), random-normalised retention, BT nodes. The front of every method is "
           "in [figures/front.png](figures/front.png).", "", plus, ""]
          if (plus := plus_targets_markdown(res)) is not None else []),
        *(["Beyond Imitation-BT+: **Imitation-BT+S** (notebook 07) evolves the small tree's "
           "structure by return; its BTs on the anchors' protocol (1,000 final episodes), "
           "against the small-BT target at 12 leaves or fewer (gymnasium's solved score from a BT "
           "small enough to read whole) and the best published small tree of each task at its "
           "own size above:", "",
           structure, ""]
          if (structure := structure_markdown(res)) is not None else []),
        *(["With tests that compare features: **Imitation-BT+SR** (notebook 07) runs the same "
           "search allowed to test `w1 * x_i + w2 * x_j <= t`; its BTs on the same protocol, "
           "against the small-BT target at 12 leaves or fewer and the published anchor at its "
           "own size above (the relational points on the front: "
           "[figures/front_relational.png](figures/front_relational.png)):", "",
           searched, ""]
          if (searched := relational_search_markdown(res)) is not None else []),
        timings_markdown(res),
        "",
        README_END,
    ])


def deviations_block(res: Results) -> str:
    """The README's generated list of deviations from the paper's setup."""
    return "\n".join([DEVIATIONS_BEGIN, "", deviations_markdown(res), "", DEVIATIONS_END])


def update_readme(readme: str | Path, block: str, begin: str = README_BEGIN,
                  end: str = README_END) -> bool:
    """Replace the text between ``begin`` and ``end`` with ``block``; True if it changed."""
    from ibt.files import atomic_write_text

    path = Path(readme)
    text = path.read_text()
    if begin not in text or end not in text:
        raise ValueError(f"{path} lacks the markers {begin!r} ... {end!r}")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    new = head + block + tail
    if new != text:
        atomic_write_text(path, new)
    return new != text
