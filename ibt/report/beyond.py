"""Beyond the paper: results the paper does not have, each a part of the reproduction report.

Each part (:data:`BEYOND`) reads its own committed table under ``data/results/`` and says "not
measured" while it is absent. To add one, append a :class:`BeyondPart` whose ``render`` returns
markdown, or ``None`` when its input is missing. ``paper/results.md``
(:func:`ibt.report.markdown.results_markdown`) shows some of the same tables.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import pandas as pd

from ibt.report.claims import NOT_MEASURED
from ibt.report.stats import Results


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


def _bar_name(source: str) -> str:
    """A bar's source as public text names it: the published policy, or "the small-BT bar"
    (at most 25 BT nodes and a mean return of at least 200 on LunarLander over 3 seeds) for
    the bar this project set itself (results tables written before it had that name say
    "issues ...")."""
    return "the small-BT bar" if source.lower().startswith("issue") else source


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
           + (f" ({_bar_name(first['bar_source'])})" if isinstance(first.get("bar_source"), str)
              else ""))
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
        "the small-BT bar (at most 25 nodes, a mean return of at least 200); otherwise the "
        "best published small policy of the task (MENS-DT-RL, Costa et al. 2024) at its own "
        "size.", structure_markdown(res))


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
