"""Relational trees on the front: cached distillation, refinement and result rows.

``imitation-bt+rel`` is the interactive loop in Imitation-BT's setting with the relational
learner (:func:`ibt.distill.relational.fit_relational_tree`); ``imitation-bt+rel+`` is its tree
refined by return (:func:`ibt.refine.relational.refine_relational`: CMA-ES on every threshold,
relational ones included, leaf sweeps, pruning). Both are cached under their own kinds
(``distill-rel``, ``refine-rel``), so the paper's kinds and their entries are untouched; BT
sizes (``front-bt``) and final evaluations (``tree-eval``) go through the front's own cached
functions, whose keys hold the tree's digest (a relational tree's feature map included).

:func:`relational_row` returns one front-like row per run; :func:`relational_table` many,
for notebook 07: ``relational_table(cfg, [("LunarLander-v3", "ppo")], seeds=[0, 1, 2],
leaves=[8])``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from ibt.distill.loop import Distillation
from ibt.engine.budgets import RELATIONAL
from ibt.profiles import Config
from ibt.refine.by_return import Refinement
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import RefineConfig
from ibt.tasks.task import Task

METHOD = RELATIONAL  # the distillation method (ibt.distill.loop.METHODS)
REFINED = "imitation-bt+rel+"  # its tree refined by return


def distill_rel(cfg: Config, task: Task, algo: str, seed: int, leaves: int | None = None, *,
                checkpoint: str | Path | None = None) -> Distillation:
    """An ``imitation-bt+rel`` distillation at a leaf limit (``None``: the task's budget) of
    the committed expert or ``checkpoint``: the engine's stage
    (:func:`ibt.engine.distil.distillation`), cached on the checkpoint's digest, the
    loop's settings and the learner's."""
    from ibt.engine.agent import committed_agent, sb3_agent
    from ibt.engine.distil import distillation

    agent = (committed_agent(task, algo, cfg.experts_dir) if checkpoint is None
             else sb3_agent(task, algo, checkpoint, check=False))
    overrides: dict[str, Any] = {} if leaves is None else {"max_leaf_nodes": leaves}
    return distillation(cfg, agent, seed, "relational", **overrides)


def refined_tree(cfg: Config, task: Task, algo: str, seed: int, leaves: int | None,
                 config: RefineConfig | None = None) -> tuple[Any, Refinement]:
    """``imitation-bt+rel+``: the distilled relational tree at ``leaves``, refined by return
    with the task's budget (:func:`ibt.engine.budgets.refine_config`, pruned to ``leaves``)."""
    from ibt.engine.budgets import refine_config
    from ibt.engine.refine import refinement_cached
    from ibt.refine.relational import best_tree

    tree = distill_rel(cfg, task, algo, seed, leaves).best_tree
    config = config or refine_config(cfg, task, max_leaves=leaves)
    record = refinement_cached(cfg, task, algo, seed, METHOD, tree, config)
    return best_tree(record), record


def relational_row(cfg: Config, task: str | Task, algo: str, seed: int, leaves: int | None,
                   refined: bool = True, config: RefineConfig | None = None
                   ) -> dict[str, Any]:
    """One front-like row: task, expert, method, seed, leaf limit, leaves, BT nodes (the
    smallest verified BT of the front's synthesisers), relational tests (of that BT and of
    the tree), final mean return and retention (the profile's final episodes)."""
    from ibt.distill.relational import relational_tests
    from ibt.engine.measure import evaluate_tree, expert_evaluation
    from ibt.evaluate.rollouts import retention_norm, retention_raw
    from ibt.runs.front import bt_sizes

    spec = get_task(task)
    run = distill_rel(cfg, spec, algo, seed, leaves)
    tree, record = run.best_tree, None
    if refined:
        tree, record = refined_tree(cfg, spec, algo, seed, leaves, config)
    sizes = bt_sizes(cfg, spec, tree)
    from ibt.bt.model import BehaviorTree

    bt = BehaviorTree.from_dict(sizes["bt"])
    evaluation = evaluate_tree(cfg, spec, tree)
    expert = expert_evaluation(cfg, spec, algo)["mean_return"]
    random_return = spec.random_return(cfg.experts_dir)
    row: dict[str, Any] = {
        "task": spec.name, "expert": algo, "method": REFINED if refined else METHOD,
        "seed": seed, "max_leaf_nodes": leaves or spec.budget.max_leaf_nodes,
        "leaves": int(tree.get_n_leaves()), "tree_relational_tests": relational_tests(tree),
        "bt_nodes": sizes["bt_nodes"], "bt_method": sizes["bt_method"],
        "bt_conditions": sizes["bt_conditions"], "relational_tests": bt.relational_count,
        "distill_seconds": round(run.wall_seconds, 2),
        "refine_episodes": record.episodes if record else 0,
        "refine_seconds": round(record.cpu_seconds, 2) if record else 0.0,
        "mean_return": evaluation["mean_return"], "std_return": evaluation["std_return"],
        "episodes": cfg.final_episodes, "expert_return": expert,
        "random_return": random_return,
        "retention_raw": retention_raw(evaluation["mean_return"], expert),
        "retention_norm": retention_norm(evaluation["mean_return"], expert, random_return)}
    return row


def relational_table(cfg: Config, experts: list[tuple[str, str]], seeds: list[int],
                     leaves: list[int | None], refined: bool = True) -> pd.DataFrame:
    """:func:`relational_row` for every (task, expert), seed and leaf limit, in that order."""
    runs = [(t, a, s, L) for t, a in experts for L in leaves for s in seeds]
    rows = [relational_row(cfg, t, a, s, L, refined)
            for t, a, s, L in tqdm(runs, desc="relational", disable=not cfg.progress)]
    return pd.DataFrame(rows)
