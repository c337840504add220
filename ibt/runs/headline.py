"""The headline BTs, chosen from the committed results (never rerun) and read back from the cache.

For every task with a published small policy to compare with (:data:`ibt.runs.anchors.DISCRETE`,
:data:`ibt.runs.anchors.CONTINUOUS`) or a continuous target (:data:`ibt.runs.continuous.TARGETS`),
two BTs are picked from the committed result tables (``data/results/``):

* the **smallest BT that keeps >= 95 %** of its agent (random-normalised retention; ties: the
  higher mean return); where no run reaches 95 %, the run that keeps the most, said so;
* the **best BT at the best published tree's size**: the highest mean return among the BTs
  whose tree has at most as many leaves as the task's best published tree.

Each task's runs are read on its 1,000-episode evaluations (the anchors' protocol) where the
project has them, on its 100 final episodes otherwise; the ``episodes`` column says which.
:func:`bt_of` reads a picked row's BT back from the cache entries its run wrote (notebooks 07
and 10); :mod:`ibt.views.headline` writes the files and ``data/results/headline.csv``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ibt.bt.model import BehaviorTree
from ibt.evaluate.rollouts import retention_norm_column
from ibt.paths import DATA_DIR
from ibt.profiles import Config
from ibt.tasks.catalogue import get_task

KEEP = 95.0  #: % random-normalised retention the smallest BT must keep
SMALLEST, AT_PUBLISHED = "smallest >= 95 %", "best at the published size"
CLOSEST = "closest to 95 % (none reaches it)"


def anchors() -> pd.DataFrame:
    """Every published small policy (source, task, leaves, mean_return), both tables."""
    from ibt.runs import anchors as published

    return pd.DataFrame([{"source": a.source, "task": a.task, "leaves": a.leaves,
                          "nodes": a.nodes, "mean_return": a.mean_return}
                         for a in (*published.DISCRETE, *published.CONTINUOUS)
                         if a.leaves is not None])


def headline_tasks() -> list[str]:
    """Tasks with a published anchor or a continuous target, in a stable order."""
    from ibt.runs import continuous

    names = [*anchors()["task"], *(t for t, _, _ in continuous.TARGETS)]
    return list(dict.fromkeys(names))


def candidates(results: Path) -> pd.DataFrame:
    """One row per committed run with a BT: its size, its evaluation and how to find it."""
    front = pd.read_csv(results / "front.csv")
    front = front.assign(episodes=100, share_200=np.nan, leaf_limit=front.max_leaf_nodes,
                         source="front.csv")
    agents = front.drop_duplicates(["task", "expert"])[["task", "expert", "expert_return",
                                                        "random_return"]]
    protocol = pd.read_csv(results / "front_protocol.csv").merge(agents, on=["task", "expert"])
    protocol = protocol.assign(method="imitation-bt+s", leaf_limit=protocol.max_leaf_nodes,
                               share_200=protocol.share_at_threshold,
                               source="front_protocol.csv")
    searched = pd.read_csv(results / "relational_search.csv").merge(agents,
                                                                    on=["task", "expert"])
    searched = searched.assign(episodes=searched.protocol_episodes,
                               mean_return=searched.protocol_mean_return,
                               std_return=searched.protocol_std_return,
                               share_200=searched.share_at_threshold,
                               leaf_limit=searched.max_leaf_nodes,
                               source="relational_search.csv")
    box = []
    for name in ("continuous.csv", "continuous_protocol.csv"):
        if (results / name).exists():
            part = pd.read_csv(results / name)
            box.append(part.assign(expert=part.algo, tree_leaves=part.leaves, source=name,
                                   method=part.method.where(~part.refined,
                                                            part.method + ", refined")))
    table = pd.concat([front, protocol, searched, *box], ignore_index=True)
    steering = _controller_rows(results, table)
    if steering is not None:
        table = pd.concat([table, steering], ignore_index=True)
    table["retention_norm"] = retention_norm_column(table.mean_return, table.expert_return,
                                             table.random_return)
    # the share of episodes >= 200 is LunarLander's "solved" landing; elsewhere it means nothing
    table.loc[~table.task.str.startswith("LunarLander"), "share_200"] = np.nan
    return table


def _controller_rows(results: Path, runs: pd.DataFrame) -> pd.DataFrame | None:
    """The controllers study's BTs (``controllers.csv``: linear commands, tests of up to four
    features) as candidates, on their agents' returns as the other runs have them."""
    from ibt.runs.controllers import OURS

    if not (results / "controllers.csv").exists():
        return None
    study = pd.read_csv(results / "controllers.csv")
    study = study[study.learner.isin(OURS)]
    agents = runs.drop_duplicates(["task", "expert"])[["task", "expert", "expert_return",
                                                       "random_return"]]
    study = study.rename(columns={"agent": "expert"}).merge(agents, on=["task", "expert"])
    return study.assign(method=study.learner + " BT", tree_leaves=study.rules,
                        leaf_limit=study.leaves_limit, share_200=study.share_at_200,
                        source="controllers.csv")


def select(table: pd.DataFrame, tasks: list[str], published: pd.DataFrame) -> pd.DataFrame:
    """The two headline rows of each task (see the module's docstring)."""
    rows = []
    for task in tasks:
        runs = table[table.task == task]
        if runs.empty:
            continue
        runs = runs[runs.episodes == runs.episodes.max()]  # 1,000 episodes where there are
        keeping = runs[runs.retention_norm >= KEEP]
        if keeping.empty:
            rows.append(runs.sort_values("retention_norm").iloc[-1:].assign(what=CLOSEST))
        else:
            rows.append(keeping.sort_values(["bt_nodes", "mean_return"],
                                            ascending=[True, False]).iloc[:1]
                        .assign(what=SMALLEST))
        anchor = published[published.task == task].sort_values("mean_return")
        if anchor.empty:
            continue
        best = anchor.iloc[-1]
        fits = runs[runs.tree_leaves <= best.leaves]
        if not fits.empty:
            rows.append(fits.sort_values(["mean_return", "bt_nodes"], ascending=[False, True])
                        .iloc[:1].assign(what=AT_PUBLISHED))
    picked = pd.concat(rows, ignore_index=True) if rows else table.iloc[:0].assign(what="")
    return picked.merge(_best_anchor(published), on="task", how="left")


def _best_anchor(published: pd.DataFrame) -> pd.DataFrame:
    best = published.sort_values("mean_return").groupby("task").tail(1)
    return best.rename(columns={"source": "anchor", "leaves": "anchor_leaves",
                                "nodes": "anchor_tree_nodes", "mean_return": "anchor_return"})


def paper_method(results: Path) -> pd.DataFrame:
    """The paper's method as reproduced here: Imitation-BT's mean BT nodes and retention per
    task and expert (``synthesis.csv``, 100 final episodes, mean over seeds)."""
    syn = pd.read_csv(results / "synthesis.csv")
    syn = syn[syn.method == "imitation-bt"]
    return (syn.groupby(["task", "expert"], as_index=False)
            .agg(paper_method_nodes=("nodes", "mean"),
                 paper_method_retention=("retention_norm", "mean")))


def headline_table(results: Path = DATA_DIR / "results", tasks: list[str] | None = None
                   ) -> pd.DataFrame:
    """The headline rows (no files): selection, anchors on each agent's scale, the paper."""
    from ibt.report.claims import PAPER_RULE_NODES

    published = anchors()
    picked = select(candidates(results), tasks or headline_tasks(), published)
    picked["anchor_retention"] = retention_norm_column(picked.anchor_return,
                                                       picked.expert_return, picked.random_return)
    picked = picked.merge(paper_method(results), on=["task", "expert"], how="left")
    # the paper's own number, where it gives one: its MountainCar BT's node count
    picked["paper_bt_nodes"] = np.where(picked.task == "MountainCar-v0", PAPER_RULE_NODES,
                                        np.nan)
    picked["name"] = [_name(r) for r in picked.itertuples()]
    return picked


def _name(row: Any) -> str:
    """The run's folder name: one per BT, whichever headline rows it fills."""
    method = str(row.method).replace("+", "-plus-")
    episodes = "" if row.episodes == 100 else f"-e{int(row.episodes)}"
    name = f"{row.task}-{row.expert}-{method}-s{int(row.seed)}-L{int(row.leaf_limit)}{episodes}"
    return re.sub(r"-+", "-", re.sub(r"[^A-Za-z0-9_.-]+", "-", name))


def bt_of(cfg: Config, row: Any) -> BehaviorTree:
    """The BT of a picked row, read back from the cache entries its run wrote."""
    from ibt.runs import continuous, front, search
    from ibt.runs.relational_search import relational_search_run

    task = get_task(row.task)
    seed, limit = int(row.seed), int(row.leaf_limit)
    if row.source == "controllers.csv":
        from ibt.runs.controllers import controller_bt

        return controller_bt(cfg, task, row.expert, limit, seed)
    if str(row.source).startswith("continuous"):
        method, _, refined = str(row.method).partition(", ")
        return continuous.point_bt(cfg, continuous.BoxPoint(row.task, row.expert, method, seed,
                                                            limit, bool(refined)))
    if row.source == "relational_search.csv":
        plus = [int(n) for n in re.findall(r"Imitation-BT\+ at (\d+) leaves", row.seeded_with)]
        chosen = None if pd.isna(row.selection_episodes) else int(row.selection_episodes)
        tree = relational_search_run(
            cfg, task, row.expert, seed, limit, plus, int(row.search_budget),
            row.candidate_weights == "scaled to spreads", row.leaf_rule, chosen).tree
    elif row.method == front.STRUCTURE:
        tree = search.structure_run(cfg, task, row.expert, seed, limit).tree
    elif row.method == front.PLUS:
        tree = front.plus_run(cfg, task, row.expert, seed, limit).tree
    else:
        leaves = None if limit == task.budget.max_leaf_nodes else limit
        tree = front.source_run(cfg, task, row.expert, row.method, seed, leaves).best_tree
    return BehaviorTree.from_dict(front.bt_sizes(cfg, task, tree)["bt"])


__all__ = ["AT_PUBLISHED", "CLOSEST", "KEEP", "SMALLEST", "anchors", "bt_of", "candidates",
           "headline_table", "headline_tasks", "paper_method", "select"]
