"""Imitation-BT+S on the front: structure search by return, then a polish, cached per run.

Beyond the paper. For one task, expert, seed and leaf limit:

1. **seed trees**: Imitation-BT+'s tree at the task's budget and the best of the four paper
   methods' grid trees by their held-out selection score (a fixed set: the same cells whatever
   else the cache holds), each cut down to the leaf limit by return;
2. **structure search** (:func:`ibt.refine.structure.evolve`): splits, features, thresholds and
   leaves evolved on return under the leaf limit, helped by the expert's labels on the states
   the small trees visit;
3. **polish** (:func:`ibt.refine.by_return.refine`): CMA-ES on the winner's thresholds, then
   pruning that costs no return, each compared on held-out episodes.

Its budget is the task's catalogue entry (``Task.evolve``), in episodes; a run records its CPU
seconds and environment steps. The anchors' protocol, 1,000 final episodes of the committed BT
with the share of episodes at or above a return, is
:func:`ibt.engine.measure.protocol_evaluation`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ibt.bt.model import BehaviorTree
from ibt.engine.agent import committed_agent
from ibt.engine.budgets import evolve_config, polish_config
from ibt.engine.measure import evaluate_tree, expert_evaluation, protocol_evaluation
from ibt.engine.refine import refinement_cached
from ibt.engine.search import evolve_one
from ibt.evaluate.rollouts import retention_norm
from ibt.profiles import Config
from ibt.refine.by_return import Refinement
from ibt.refine.structure import Evolution
from ibt.runs.front import STRUCTURE, plus_run, ranked_sources
from ibt.tasks.catalogue import get_task
from ibt.tasks.task import Task

__all__ = ["STRUCTURE", "evolve_cached", "expert_help_table", "protocol_evaluation",
           "structure_run"]


def seed_trees(cfg: Config, task: Task, algo: str, seed: int) -> list[Any]:
    """Imitation-BT+'s tree at the task's budget, and the grid tree (of the four paper
    methods) that scored best on its held-out selection episodes; the search cuts either down
    to its leaf limit by return."""
    best_grid = ranked_sources(cfg, task, algo, seed)[0][1].best_tree
    return [plus_run(cfg, task, algo, seed, None).tree, best_grid]


def evolve_cached(cfg: Config, task: str | Task, algo: str, seed: int, max_leaves: int,
                  use_expert: bool = True) -> Evolution:
    """The structure search of one run: the engine's stage
    (:func:`ibt.engine.search.evolve_one`) from this study's seed trees, cached on them and
    its settings."""
    spec = get_task(task)
    config = evolve_config(cfg, spec, max_leaves, use_expert)
    return evolve_one(cfg, committed_agent(spec, algo, cfg.experts_dir),
                      seed_trees(cfg, spec, algo, seed), config, seed, relational=False,
                      agent_in_key=False)


@dataclass(frozen=True)
class StructureResult:
    """Imitation-BT+S for one task, expert, seed and leaf limit, with what it cost."""

    evolution: Evolution
    polish: Refinement

    @property
    def tree(self) -> Any:
        return self.polish.best_tree

    @property
    def cpu_seconds(self) -> float:
        return self.evolution.cpu_seconds + self.polish.cpu_seconds

    @property
    def episodes(self) -> int:
        return self.evolution.episodes + self.polish.episodes

    @property
    def steps(self) -> int:
        return self.evolution.steps + self.polish.steps


def structure_run(cfg: Config, task: str | Task, algo: str, seed: int, max_leaves: int,
                  use_expert: bool = True) -> StructureResult:
    """Structure search, then the polish of its winner (each cached); ``use_expert=False``:
    the ablation that searches on reward alone."""
    spec = get_task(task)
    evolution = evolve_cached(cfg, spec, algo, seed, max_leaves, use_expert)
    polish = polish_config(cfg, evolve_config(cfg, spec, max_leaves, use_expert))
    return StructureResult(evolution, refinement_cached(cfg, spec, algo, seed, STRUCTURE,
                                                        evolution.best_tree, polish))


def structure_points(experts: dict[str, list[str]], leaves: dict[str, list[int]],
                     seeds: list[int]) -> list[Any]:
    """Imitation-BT+S for each task's experts at each of its leaf limits (front points)."""
    from ibt.runs.front import Point

    return [Point(task, algo, STRUCTURE, s, L) for task, algos in experts.items()
            for algo in algos for L in leaves.get(task, []) for s in seeds]


def protocol_table(cfg: Config, table: Any, threshold: dict[str, float] | None = None,
                   episodes: int = 1000) -> Any:
    """Every Imitation-BT+S run of the front table on the anchors' protocol: its smallest
    verified BT (rebuilt from the cached document) on ``episodes`` final episodes; one row
    per run, with the share of episodes at or above the task's ``threshold`` (LunarLander:
    200, the "solved" landing)."""
    import pandas as pd

    from ibt.runs.front import bar_of, bt_sizes

    threshold = threshold or {}
    rows = []
    for run in table[table["method"] == STRUCTURE].itertuples(index=False):
        found = structure_run(cfg, run.task, run.expert, int(run.seed), int(run.max_leaf_nodes))
        bt = BehaviorTree.from_dict(bt_sizes(cfg, run.task, found.tree)["bt"])
        result = protocol_evaluation(cfg, get_task(run.task), bt, episodes,
                                     threshold.get(run.task))
        rows.append({"task": run.task, "expert": run.expert, "max_leaf_nodes": run.max_leaf_nodes,
                     "seed": run.seed, "tree_leaves": run.tree_leaves, "bt_nodes": bt.node_count,
                     "episodes": result["episodes"], "mean_return": result["mean_return"],
                     "std_return": result["std_return"],
                     "share_at_threshold": result["share_at_threshold"],
                     "threshold": result["threshold"],
                     "cpu_seconds": run.refine_seconds, "env_steps": run.refine_steps,
                     "search_steps_per_second": round(found.evolution.steps_per_second),
                     "random_steps_per_second": round(found.evolution.random_steps_per_second),
                     **bar_of(run.task, int(run.max_leaf_nodes))})
    return pd.DataFrame(rows)


def expert_help_table(cfg: Config, experts: dict[str, list[str]], leaves: dict[str, list[int]],
                      seeds: list[int]) -> Any:
    """What the expert's help adds to the structure search: each run with its labels ("grow"
    by a CART stump on them, "relabel" by its majority) and without (reward alone), on the
    same seed trees, budget and seeds; the polished tree's 100 final episodes and its
    smallest verified BT. One row per run and variant."""
    import pandas as pd

    from ibt.runs.front import bt_sizes

    rows = []
    for task, algos in experts.items():
        spec = get_task(task)
        for algo in algos:
            expert = expert_evaluation(cfg, spec, algo)["mean_return"]
            for max_leaves in leaves.get(task, []):
                for seed in seeds:
                    for use_expert in (True, False):
                        found = structure_run(cfg, spec, algo, seed, max_leaves, use_expert)
                        evaluation = evaluate_tree(cfg, spec, found.tree)
                        sizes = bt_sizes(cfg, spec, found.tree)
                        rows.append({
                            "task": spec.name, "expert": algo, "max_leaf_nodes": max_leaves,
                            "seed": seed, "expert_help": use_expert,
                            "tree_leaves": sizes["tree_leaves"], "bt_nodes": sizes["bt_nodes"],
                            "mean_return": evaluation["mean_return"],
                            "retention_norm": retention_norm(
                                evaluation["mean_return"], expert,
                                spec.random_return(cfg.experts_dir)),
                            "cpu_seconds": round(found.cpu_seconds, 1)})
    return pd.DataFrame(rows)
