"""The paper's grid as markdown tables: retention, node counts, the headline, the aggregate,
the experts, the stages' times and the claims' verdicts.

The numbers come from :mod:`ibt.report.stats` (intervals, aggregates) reading the committed
tables only (``data/results/*.csv``, their manifests, ``data/experts/manifest.csv``); here is
formatting. The documents (:mod:`ibt.report.markdown`) put these tables together.

Cells of a table print ``mean [a, b]`` when ``[a, b]`` is a 95 % percentile bootstrap CI (5 or
more seeds) and ``mean (a to b, n seeds)`` when it is the range of fewer seeds. Experts whose
status is not ``ok`` are marked (:data:`STATUS_MARKS`) and explained in a footnote.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ibt.report.claims import SIMPLE_TASKS, STOCHASTIC_TASKS, TREE_METHODS
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
from ibt.report.text import md

METHODS = (*TREE_METHODS, "bt-espresso", "re-bt-espresso")
STATUS_MARKS = {"excluded": "‡", "constant-action": "†"}
INTERVAL_LEGEND = (f"Each cell is the mean over seeds: `m [a, b]` gives the 95 % percentile "
                   f"bootstrap CI of the mean (cells with {MIN_SEEDS_FOR_CI} or more seeds), "
                   f"`m (a to b, n seeds)` the range, min to max, of fewer seeds (not a "
                   f"confidence interval).")


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
    return f"{md(expert)} {mark}" if mark else md(expert)


def status_footnotes(res: Results, shown: pd.DataFrame | None = None) -> str:
    """One line per expert that is not ``ok`` (among ``shown``'s task/expert pairs)."""
    lines = []
    pairs = None if shown is None else set(zip(shown["task"], shown["expert"], strict=True))
    for (task, algo), (status, evidence) in sorted(res.expert_status().items()):
        if status == "ok" or (pairs is not None and (task, algo) not in pairs):
            continue
        what = "excluded" if status == "excluded" else "constant-action expert"
        lines.append(f"{STATUS_MARKS.get(status, '')} {md(task)} {md(algo)}: {what} "
                     f"({md(evidence)}); "
                     "its cells stay in the tables and count in no claim.")
    return "\n".join(f"- {line}" for line in lines)


def distillation_grid(res: Results) -> pd.DataFrame | None:
    """The distillation table with expert statuses; None when absent or missing a column."""
    grid = res.table("distillation")
    if grid is None or not {"task", "expert", "method", "retention_norm"} <= set(grid.columns):
        return None
    return with_expert_status(grid, res.expert_status())


def retention_markdown(res: Results, value: str = "retention_norm") -> str:
    """Task x expert rows, one column per method, each cell with its interval."""
    grid = distillation_grid(res)
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
        lines.append(f"| {md(task)} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def nodes_markdown(res: Results) -> str:
    """Mean node counts: trees for BC/DAgger/VIPER, BTs for the synthesis methods."""
    grid, syn = distillation_grid(res), res.table("synthesis")
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
        lines.append(f"| {md(task)} | {label} | " + " | ".join(_fmt(row[m], 1) for m in present)
                     + " |")
    return "\n".join(lines)


def headline_markdown(res: Results) -> str:
    """The README's headline: Imitation-BT vs BC retention and BT size vs RE:BT per task."""
    grid = distillation_grid(res)
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
        lines.append(f"| {md(task)} | {_expert_label(expert, part.expert_status.iloc[0])} | "
                     f"{expert_return} | {format_cell(bc.retention_norm.to_numpy())} | "
                     f"{format_cell(ours.retention_norm.to_numpy())} | {nodes[0]} | "
                     f"{nodes[1]} |")
    return "\n".join(lines)


def aggregate_markdown(res: Results) -> str:
    """IQM retention per method over the counted cells of each task group, stratified CI."""
    grid = distillation_grid(res)
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
        lines.append(f"| {md(r.task)} | {md(r.algo)} | {md(r.net_arch)} | {int(r.timesteps):,} | "
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
                     f"machine: {md(res.manifest(name).get('machine', '?'))} |")
    figures = res.results_dir / "make_figures.json"
    if figures.exists() and with_record:
        facts = json.loads(figures.read_text())
        lines.append(f"| `make figures`, last run (venv ready) | 1 | "
                     f"{facts['seconds']:.0f} s wall | "
                     f"{md(facts.get('machine', ''))}, {md(facts.get('date', ''))} |")
    elif figures.exists():  # a number here would change this file on every run
        lines.append("| `make figures` (venv ready) | 1 | wall time of the last run: "
                     "`data/results/make_figures.json` | written at the end of each run |")
    return "\n".join(lines)


def claims_markdown(frame: pd.DataFrame) -> str:
    lines = ["| claim | verdict | measured |", "|---|---|---|"]
    for row in frame.itertuples():
        lines.append(f"| {row.claim} | **{row.verdict}** | {row.measured} |")
    return "\n".join(lines)
