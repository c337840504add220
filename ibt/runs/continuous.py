"""Continuous actions, cached: distil into regression trees, merge leaves into named
commands, refine the command tree by return (Imitation-BT+ for continuous actions), synthesise
every verified BT and evaluate it rolled out from its JSON document.

Each step is one cache kind of :data:`ibt.cache.store.CODE_VERSIONS` with a plain JSON payload:

* ``box-distill``: :func:`ibt.distill.continuous.distill_box` (iterations and the best
  regression tree, :func:`ibt.distill.continuous.regressor_doc`);
* ``box-commands``: :func:`ibt.synth.commands.choose_commands` on that tree (the fewest commands
  within 1 % of expert minus random return of the tree's own, on held-out selection episodes);
* ``box-refine``: :func:`ibt.refine.commands.refine_commands` of the command tree, with the
  task's refinement budget (its catalogue entry's ``refine``);
* ``box-eval`` (:func:`ibt.engine.measure.command_tree_evaluation`): every front
  synthesiser's BT of a command tree (each verified against it), the smallest one's JSON, and
  its return on the final episodes, rolled out from that JSON text.

The notebook (``notebooks/10_continuous.ipynb``) calls :func:`continuous_table`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pandas as pd
from tqdm import tqdm

from ibt.bt.model import BehaviorTree
from ibt.engine.agent import committed_agent
from ibt.engine.budgets import box_refine_config
from ibt.engine.commands import commands
from ibt.engine.distil import distillation
from ibt.engine.measure import command_tree_evaluation, expert_evaluation
from ibt.engine.refine import command_refinement
from ibt.evaluate.rollouts import retention_norm
from ibt.profiles import Config
from ibt.refine.commands import CommandArrays, CommandRefinement
from ibt.runs import anchors
from ibt.tasks.catalogue import get_task
from ibt.tasks.task import Task


def box_distill_cached(cfg: Config, task: str | Task, algo: str, method: str, seed: int,
                       leaves: int | None = None) -> dict[str, Any]:
    """A continuous distillation of the committed expert (the engine's stage,
    :func:`ibt.engine.distil.distillation`): ``iterations``, ``best_index``, ``tree`` (a
    :func:`ibt.distill.continuous.regressor_doc`), ``wall_seconds``."""
    spec = get_task(task)
    overrides: dict[str, Any] = {} if leaves is None else {"max_leaf_nodes": leaves}
    return distillation(cfg, committed_agent(spec, algo, cfg.experts_dir), seed, "box",
                               method, **overrides)


def commands_cached(cfg: Config, task: str | Task, algo: str, method: str, seed: int,
                    leaves: int | None = None) -> dict[str, Any]:
    """The distilled tree's leaves merged into the fewest named commands that keep its
    held-out return (:func:`ibt.engine.commands.commands`)."""
    spec = get_task(task)
    run = box_distill_cached(cfg, spec, algo, method, seed, leaves)
    return commands(cfg, committed_agent(spec, algo, cfg.experts_dir), run["tree"], seed)


def command_refinement_of(cfg: Config, task: str | Task, algo: str, method: str, seed: int,
                          leaves: int | None = None) -> CommandRefinement:
    """The command tree of :func:`commands_cached`, refined by return with the task's budget
    (:func:`ibt.engine.refine.command_refinement`)."""
    spec = get_task(task)
    source = commands_cached(cfg, spec, algo, method, seed, leaves)["arrays"]
    return command_refinement(cfg, committed_agent(spec, algo, cfg.experts_dir),
                              CommandArrays.from_doc(source), seed, box_refine_config(cfg, spec))


@dataclass(frozen=True)
class BoxPoint:
    """One continuous run: a method's tree at a leaf limit, refined or not, for one seed."""

    task: str
    algo: str
    method: str
    seed: int
    leaves: int | None
    refined: bool


def point_arrays(cfg: Config, point: BoxPoint) -> tuple[CommandArrays, dict[str, Any]]:
    """A point's command tree and what made it (commands chosen, refinement)."""
    spec = get_task(point.task)
    chosen = commands_cached(cfg, spec, point.algo, point.method, point.seed, point.leaves)
    info: dict[str, Any] = {"commands_tree_return": chosen["rows"][-1]["tree_return"]}
    if not point.refined:
        return CommandArrays.from_doc(chosen["arrays"]), info
    record = command_refinement_of(cfg, spec, point.algo, point.method, point.seed,
                                   point.leaves)
    info.update({"refine_episodes": record.episodes, "refine_cpu_s": record.cpu_seconds,
                 "refine_steps": record.steps,
                 "selection_before": record.selection_means[0],
                 "selection_after": record.selection_means[record.best_index]})
    return record.best, info


def point_row(cfg: Config, point: BoxPoint, episodes: int | None = None) -> dict[str, Any]:
    """One row of the continuous table: sizes, commands, return and retention."""
    spec = get_task(point.task)
    arrays, info = point_arrays(cfg, point)
    result = command_tree_evaluation(cfg, spec, arrays, episodes)
    expert = expert_evaluation(cfg, spec, point.algo)["mean_return"]
    rand = spec.random_return(cfg.experts_dir)
    return {"task": point.task, "algo": point.algo, "method": point.method, "seed": point.seed,
            "leaf_limit": point.leaves or spec.budget.max_leaf_nodes, "refined": point.refined,
            "leaves": arrays.n_leaves, "commands": arrays.n_commands,
            "bt_method": result["bt_method"], "bt_nodes": result["bt_nodes"],
            "episodes": result["episodes"], "mean_return": result["mean_return"],
            "std_return": result["std_return"], "share_200": result["share_200"],
            "expert_return": expert, "random_return": rand,
            "retention_norm": retention_norm(result["mean_return"], expert, rand), **info}


def continuous_table(cfg: Config, points: list[BoxPoint], episodes: int | None = None
                     ) -> pd.DataFrame:
    """:func:`point_row` of every point (computed or read from the cache)."""
    rows = [point_row(cfg, p, episodes) for p in tqdm(points, desc="continuous points",
                                                      disable=not cfg.progress, leave=False)]
    return pd.DataFrame(rows)


def sweep_points(tasks: dict[str, tuple[str, str]], leaf_limits: list[int], seeds: list[int],
                 refined: bool) -> list[BoxPoint]:
    """Points of ``tasks`` (name -> (algo, method)) at every leaf limit and seed."""
    return [BoxPoint(name, algo, method, seed, leaves, refined)
            for name, (algo, method) in tasks.items() for leaves in leaf_limits
            for seed in seeds]


def point_bt(cfg: Config, point: BoxPoint) -> BehaviorTree:
    """A point's smallest verified BT (from the ``box-eval`` cache)."""
    arrays, _ = point_arrays(cfg, point)
    return BehaviorTree.from_dict(command_tree_evaluation(cfg, get_task(point.task), arrays)["bt"])


#: The done-when bars, set before the runs: (task, most leaves, least mean return).
TARGETS: tuple[tuple[str, int, float], ...] = (
    ("LunarLanderContinuous-v3", 16, 210.0), ("Pendulum-v1", 16, -250.0),
    ("MountainCarContinuous-v0", 4, 90.0))


def anchor_table(tasks: list[str]) -> pd.DataFrame:
    """:data:`ibt.runs.anchors.CONTINUOUS` of ``tasks`` (source, task, leaves, tree_nodes,
    mean_return)."""
    rows = [{"source": a.source, "task": a.task, "leaves": a.leaves, "tree_nodes": a.nodes,
             "mean_return": a.mean_return} for a in anchors.CONTINUOUS if a.task in tasks]
    return pd.DataFrame(rows, columns=["source", "task", "leaves", "tree_nodes", "mean_return"])


def target_table(table: pd.DataFrame) -> pd.DataFrame:
    """Each target against the best mean over seeds of any kind (distilled or refined) whose
    leaf limit fits the bar, on the table's final episodes."""
    rows = []
    for task, leaves, bar in TARGETS:
        runs = table[(table["task"] == task) & (table["leaf_limit"] <= leaves)]
        if runs.empty:
            continue
        means = runs.groupby(["refined", "leaf_limit"]).agg(
            seeds=("seed", "count"), leaves=("leaves", "max"), bt_nodes=("bt_nodes", "mean"),
            mean_return=("mean_return", "mean"), lowest_seed=("mean_return", "min"),
            highest_seed=("mean_return", "max")).reset_index()
        best = means.sort_values("mean_return", ascending=False).iloc[0]
        rows.append({"task": task, "max_leaves": leaves, "min_return": bar,
                     "refined": bool(best["refined"]), "leaf_limit": int(best["leaf_limit"]),
                     "seeds": int(best["seeds"]), "leaves_used": int(best["leaves"]),
                     "bt_nodes": float(best["bt_nodes"]),
                     "mean_return": float(best["mean_return"]),
                     "lowest_seed": float(best["lowest_seed"]),
                     "highest_seed": float(best["highest_seed"]),
                     "met": bool(best["mean_return"] >= bar)})
    return pd.DataFrame(rows)
