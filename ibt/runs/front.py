"""The size-retention front, and Imitation-BT+: distil, refine by return, keep the smallest BT.

Beyond the paper. Every method of the grid is distilled at several leaf limits; each tree is
turned into every available verified BT (the paper's construction and the decision list of
:mod:`ibt.synth.decision_list`), and a point of the front is (BT nodes, random-normalised
retention):
how much of the expert a BT of that size keeps. Trees and their BTs decide identically (each BT
is verified), so a tree's final evaluation is its BT's.

**Imitation-BT+** is the recipe this artifact proposes on top of the paper's method:

1. distil: the four paper methods' grid trees (the same loop in four settings, at the task's
   leaf budget) are ranked by their held-out selection score (on LunarLander the linear
   schedule of Imitation-BT loses to faster hand-overs, see notebook 02, so the paper's own
   setting is not always the best start);
2. refine the best ``Task.refine_sources`` of them by return (:func:`ibt.refine.by_return.refine`:
   thresholds by CMA-ES, leaf actions, pruning to a leaf limit), on refinement episodes
   disjoint from selection and final ones, and keep the one that scores best on the
   refinement's held-out selection episodes;
3. synthesise every verified BT of the refined tree and keep the smallest.

The four paper methods and their numbers are untouched: this module only reads their cached
distillations. :data:`ibt.runs.anchors.DISCRETE` holds the published reference points
(MENS-DT-RL), converted onto our normalised scale with our random baselines and experts.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from tqdm import tqdm

from ibt.bt.model import BehaviorTree
from ibt.cache.store import load_or_compute, tree_digest
from ibt.distill.loop import Distillation
from ibt.engine.budgets import refine_config
from ibt.engine.measure import evaluate_bt, evaluate_tree, expert_evaluation
from ibt.engine.refine import refinement_cached
from ibt.engine.synthesis import smallest_bt
from ibt.evaluate.rollouts import retention_norm, retention_raw
from ibt.profiles import Config
from ibt.refine.by_return import RefineConfig, Refinement
from ibt.runs import anchors
from ibt.runs.steps import distill_cached
from ibt.synth.registry import front_synthesisers, get_synthesiser
from ibt.tasks.catalogue import TASKS, get_task
from ibt.tasks.task import Task

PLUS = "imitation-bt+"
STRUCTURE = "imitation-bt+s"  # structure search by return, then a polish: ibt.runs.search
SOURCE_METHODS = ("bc", "dagger", "viper", "imitation-bt")


#: The bar of a small BT (the small-BT target: gymnasium's solved score, 200 on LunarLander, from a
#: BT small enough to read whole; at 12 leaves or fewer) on the anchors' protocol,
#: per task: every seed's BT at most this many nodes, the mean return over seeds (1,000 final
#: episodes each) at least this; at larger limits the bar is the task's published anchor at its
#: own size (:data:`ibt.runs.anchors.DISCRETE`: above its mean, its share, at most its BT nodes).
#: Each row carries its bar, so the report reads it from the CSV.
SMALL_BARS: dict[str, dict[str, Any]] = {
    "LunarLander-v3": {"up_to_leaves": 12, "bar_max_bt_nodes": 25, "bar_min_return": 200.0,
                       "bar_strict": False, "bar_min_share": None,
                       "bar_source": "the small-BT bar"}}
BAR_SEEDS = 3  # the bars are means over this many seeds


def bar_of(task: str, max_leaves: int) -> dict[str, Any]:
    """The ``bar_*`` columns of a run at ``max_leaves`` (all None where the task has none)."""
    small = SMALL_BARS.get(task)
    if small is not None and max_leaves <= small["up_to_leaves"]:
        return {**{k: v for k, v in small.items() if k != "up_to_leaves"},
                "bar_seeds": BAR_SEEDS}
    anchor = next((a for a in anchors.DISCRETE if a.task == task and a.max_bt_nodes
                   and a.leaves is not None and max_leaves <= a.leaves), None)
    if anchor is None:
        return dict.fromkeys(("bar_max_bt_nodes", "bar_min_return", "bar_strict",
                              "bar_min_share", "bar_source", "bar_seeds"))
    return {"bar_max_bt_nodes": anchor.max_bt_nodes, "bar_min_return": anchor.mean_return,
            "bar_strict": True, "bar_min_share": anchor.min_share, "bar_source": anchor.source,
            "bar_seeds": BAR_SEEDS}


def source_run(cfg: Config, task: str | Task, algo: str, method: str, seed: int,
               leaves: int | None) -> Distillation:
    """A cached distillation at a leaf limit (``None``: the task's budget, i.e. the grid run)."""
    task = get_task(task)
    overrides = {} if leaves is None or leaves == task.budget.max_leaf_nodes else {
        "max_leaf_nodes": leaves}
    return distill_cached(cfg, task, algo, method, seed, **overrides)


def ranked_sources(cfg: Config, task: str | Task, algo: str, seed: int
                   ) -> list[tuple[str, Distillation]]:
    """The four paper methods' grid runs (the task's leaf budget, this seed), best first by
    the held-out selection score of their chosen tree (all four use the same selection
    episodes; the final episodes are never looked at). Ties keep :data:`SOURCE_METHODS`
    order."""
    runs = [(m, source_run(cfg, task, algo, m, seed, None)) for m in SOURCE_METHODS]
    return sorted(runs, key=lambda mr: -mr[1].iterations[mr[1].best_index]["selection_mean"])


def plus_refinement(cfg: Config, task: str | Task, algo: str, seed: int, source_method: str,
                    *, max_leaves: int | None, config: RefineConfig | None = None
                    ) -> Refinement:
    """Refine one source run's tree, pruned to ``max_leaves`` (cached on tree and settings).

    ``max_leaves`` None refines without forcing the tree smaller.
    """
    spec = get_task(task)
    config = config or refine_config(cfg, spec, max_leaves=max_leaves)
    tree = source_run(cfg, spec, algo, source_method, seed, None).best_tree
    return refinement_cached(cfg, spec, algo, seed, source_method, tree, config)


@dataclass(frozen=True)
class PlusResult:
    """Imitation-BT+ for one task, expert, seed and leaf limit, with what it cost."""

    source_method: str
    refinement: Refinement  # the chosen source's
    distill_seconds: float  # the four source runs
    refine_seconds: float  # every source refined: CPU seconds (one process, one core)
    refine_episodes: int
    refine_steps: int

    @property
    def tree(self) -> Any:
        return self.refinement.best_tree


def plus_run(cfg: Config, task: str | Task, algo: str, seed: int, max_leaves: int | None
             ) -> PlusResult:
    """Imitation-BT+: refine the task's ``refine_sources`` best source trees (by their
    held-out selection score) and keep the refined tree that scores best on the refinement's
    held-out selection episodes (the same episodes for every source)."""
    task = get_task(task)
    ranked = ranked_sources(cfg, task, algo, seed)
    refined = [(m, plus_refinement(cfg, task, algo, seed, m, max_leaves=max_leaves))
               for m, _ in ranked[:task.refine_sources]]
    method, chosen = max(refined, key=lambda mr: mr[1].selection_means[mr[1].best_index])
    return PlusResult(method, chosen, sum(run.wall_seconds for _, run in ranked),
                      sum(r.cpu_seconds for _, r in refined),
                      sum(r.episodes for _, r in refined), sum(r.steps for _, r in refined))


def bt_sizes(cfg: Config, task: str | Task, tree: Any) -> dict[str, Any]:
    """Every front synthesiser's verified BT of ``tree`` (the registry's ``on_front``), their
    sizes, and the smallest (cached)."""
    spec = get_task(task)
    synthesisers = front_synthesisers()
    params = {"task": spec.name, "tree": tree_digest(tree), "synthesisers": list(synthesisers)}

    def compute() -> dict[str, Any]:
        t = tree.tree_
        out: dict[str, Any] = {"tree_nodes": int(t.node_count),
                               "tree_leaves": int(tree.get_n_leaves()),
                               "tree_splits": int(t.node_count - tree.get_n_leaves())}
        bts = {}
        for method in synthesisers:
            start = time.perf_counter()
            bt = get_synthesiser(method)(tree, spec).bt  # verified: raises if it disagrees
            key = method.replace("-", "_")
            out[f"nodes_{key}"] = bt.node_count
            out[f"conditions_{key}"] = bt.node_types()["condition"]
            out[f"seconds_{key}"] = round(time.perf_counter() - start, 3)
            bts[method] = bt
        smallest = smallest_bt(bts)
        out.update({"bt_method": smallest, "bt_nodes": bts[smallest].node_count,
                    "bt_conditions": bts[smallest].node_types()["condition"],
                    "bt": bts[smallest].to_dict()})
        return out

    return load_or_compute("front-bt", params, compute, cache_dir=cfg.cache_dir, codec="json",
                           refresh=cfg.refresh)


@dataclass(frozen=True)
class Point:
    """One run on the front: a method's tree at a leaf limit, for one expert and seed.

    For the paper's methods ``leaves`` is the distillation's leaf limit; for Imitation-BT+ it
    is the refinement's (the source is always the grid's Imitation-BT tree). None: the task's
    budget (the grid run itself; Imitation-BT+ then refines without forced pruning).
    """

    task: str
    algo: str
    method: str  # one of SOURCE_METHODS, or PLUS
    seed: int
    leaves: int | None

    def label(self) -> str:
        return f"{self.task}/{self.algo}/{self.method}/s{self.seed}/L{self.leaves}"


def point_row(cfg: Config, point: Point) -> dict[str, Any]:
    """One row of ``data/results/front.csv`` (every heavy step cached)."""
    spec = get_task(point.task)
    if point.method == PLUS:
        result = plus_run(cfg, spec, point.algo, point.seed, point.leaves)
        source_method, distill_seconds, tree = (result.source_method, result.distill_seconds,
                                                result.tree)
    elif point.method == STRUCTURE:  # beyond Imitation-BT+: ibt.runs.search
        from ibt.runs.search import structure_run

        found = structure_run(cfg, spec, point.algo, point.seed,
                              point.leaves or spec.budget.max_leaf_nodes or 16)
        source_method, tree = "seeds: imitation-bt+ and the four grid trees", found.tree
        distill_seconds = plus_run(cfg, spec, point.algo, point.seed, None).distill_seconds
    else:
        source_method = point.method
        run = source_run(cfg, spec, point.algo, point.method, point.seed, point.leaves)
        distill_seconds, tree = run.wall_seconds, run.best_tree
    row: dict[str, Any] = {"task": spec.name, "expert": point.algo, "method": point.method,
                           "seed": point.seed,
                           "max_leaf_nodes": point.leaves or spec.budget.max_leaf_nodes,
                           "source_method": source_method,
                           "distill_seconds": round(distill_seconds, 2),
                           "refine_episodes": 0, "refine_steps": 0, "refine_seconds": 0.0}
    if point.method == PLUS:
        record = result.refinement
        row.update({"refine_episodes": result.refine_episodes,
                    "refine_steps": result.refine_steps,
                    "refine_seconds": round(result.refine_seconds, 2),
                    "refine_stage": (["source"] + [s["stage"] for s in record.stages])[
                        record.best_index]})
    if point.method == STRUCTURE:
        polish = found.polish
        row.update({"refine_episodes": found.episodes, "refine_steps": found.steps,
                    "refine_seconds": round(found.cpu_seconds, 2),
                    "refine_stage": (["search"] + [s["stage"] for s in polish.stages])[
                        polish.best_index]})
    sizes = bt_sizes(cfg, spec, tree)
    evaluation = evaluate_tree(cfg, spec, tree)
    expert = expert_evaluation(cfg, spec, point.algo)["mean_return"]
    random_return = spec.random_return(cfg.experts_dir)
    row.update({k: v for k, v in sizes.items() if k != "bt"})
    row.update({"mean_return": evaluation["mean_return"], "std_return": evaluation["std_return"],
                "expert_return": expert, "random_return": random_return,
                "retention_raw": retention_raw(evaluation["mean_return"], expert),
                "retention_norm": retention_norm(evaluation["mean_return"], expert,
                                                 random_return)})
    return row


def front_table(cfg: Config, points: list[Point], n_jobs: int | None = None) -> pd.DataFrame:
    """Rows for ``points`` in order, computed by ``n_jobs`` processes (default: the profile's).

    Cached points load instantly; every run is deterministic in its seed, so the number of
    processes never changes a row.
    """
    from dataclasses import asdict

    from joblib import Parallel, delayed

    n_jobs = n_jobs or cfg.n_jobs
    quiet = Config(**{**asdict(cfg), "progress": False})
    jobs = Parallel(n_jobs=n_jobs, return_as="generator")(
        delayed(point_row)(quiet, p) for p in points)
    rows = list(tqdm(jobs, total=len(points), desc="front", disable=not cfg.progress))
    return pd.DataFrame(rows)


def anchor_table(cfg: Config, experts: list[tuple[str, str]]) -> pd.DataFrame:
    """The published anchors on our normalised scale, once per (task, expert) given."""
    rows = []
    for anchor in anchors.DISCRETE:
        for task, algo in experts:
            if task != anchor.task:
                continue
            spec = get_task(task)
            expert = expert_evaluation(cfg, spec, algo)["mean_return"]
            rows.append({"source": anchor.source, "task": task, "expert": algo,
                         "tree_nodes": anchor.nodes, "tree_leaves": anchor.leaves,
                         "mean_return": anchor.mean_return,
                         "retention_norm": retention_norm(anchor.mean_return, expert,
                                                          spec.random_return(cfg.experts_dir))})
    return pd.DataFrame(rows, columns=["source", "task", "expert", "tree_nodes", "tree_leaves",
                                       "mean_return", "retention_norm"])


def committed_bt(cfg: Config, task: str, algo: str, seeds: list[int], leaves: int | None
                 ) -> dict[str, Any]:
    """The Imitation-BT+ BT of the seed that scored best on the final episodes, rolled out.

    The BT is rolled out in the environment from its own JSON document; ``matches_tree`` says
    whether its mean return equals its (refined) tree's.
    """
    rows = [point_row(cfg, Point(task, algo, PLUS, s, leaves)) for s in seeds]
    best = max(rows, key=lambda r: (r["mean_return"], -r["bt_nodes"], -r["seed"]))
    sizes = bt_sizes(cfg, task, plus_run(cfg, task, algo, int(best["seed"]), leaves).tree)
    bt = BehaviorTree.from_dict(sizes["bt"])
    rollout = evaluate_bt(cfg, get_task(task), bt)
    return {"bt": bt, "seed": int(best["seed"]), "mean_return": rollout["mean_return"],
            "matches_tree": bool(np.isclose(rollout["mean_return"], best["mean_return"]))}


def front_means(table: pd.DataFrame) -> pd.DataFrame:
    """Per (task, expert, method, leaf limit): mean BT nodes and retention, with the interval
    over seeds named for what it is (:func:`ibt.report.stats.interval`)."""
    from ibt.report.stats import interval

    rows = []
    keys = ["task", "expert", "method", "max_leaf_nodes"]
    for key, group in table.groupby(keys, sort=False):
        iv = interval(group["retention_norm"].to_numpy())
        rows.append({**dict(zip(keys, key, strict=True)), "n": iv.n,
                     "bt_nodes": group["bt_nodes"].mean(),
                     "bt_nodes_min": group["bt_nodes"].min(),
                     "bt_nodes_max": group["bt_nodes"].max(),
                     "tree_leaves": group["tree_leaves"].mean(),
                     "retention_norm": iv.mean, "low": iv.low, "high": iv.high,
                     "interval": iv.label,
                     "mean_return": group["mean_return"].mean()})
    return pd.DataFrame(rows)


def sweep_points(tasks: list[str], algo: str, methods: list[str],
                 leaves: dict[str, list[int]], seeds: list[int]) -> list[Point]:
    """The paper methods at each task's leaf limits (the task's budget added: the grid run)."""
    points = []
    for task in tasks:
        budget = get_task(task).budget.max_leaf_nodes
        limits = sorted({*leaves.get(task, []), budget or 0} - {0})
        points += [Point(task, algo, m, s, None if L == budget else L)
                   for m in methods for L in limits for s in seeds]
    return points


def plus_points(experts: dict[str, list[str]], headline: dict[str, int | None],
                sweep_expert: str, leaves: dict[str, list[int | None]], seeds: list[int]
                ) -> list[Point]:
    """Imitation-BT+ for each task's experts at its headline leaf limit, and for the sweep
    expert at every limit of ``leaves`` too (the front)."""
    points = []
    for task, algos in experts.items():
        for algo in algos:
            limits = [headline.get(task)]
            if algo == sweep_expert:
                limits += [L for L in leaves.get(task, []) if L != headline.get(task)]
            points += [Point(task, algo, PLUS, s, L) for L in limits for s in seeds]
    return points


def without_pending(points: list[Point], pending: list[list[Any]]) -> list[Point]:
    """Drop points listed as ``[task, expert]``, ``[task, expert, method]``,
    ``[task, expert, method, leaves]`` or ``[task, expert, method, leaves, seed]`` (runs not
    computed yet)."""
    def listed(p: Point) -> bool:
        keys = ([p.task, p.algo], [p.task, p.algo, p.method], [p.task, p.algo, p.method, p.leaves],
                [p.task, p.algo, p.method, p.leaves, p.seed])
        return any(list(k) in pending for k in keys)

    return [p for p in points if not listed(p)]


def targets() -> list[Task]:
    """The registered tasks with an Imitation-BT+ target (``Task.front_target``), in the
    targets table's order."""
    with_target = [t for t in TASKS.values() if t.front_target is not None]
    return sorted(with_target, key=lambda t: t.front_target.rank)  # type: ignore[union-attr]


def target_table(table: pd.DataFrame, headline: dict[str, int | None]) -> pd.DataFrame:
    """Each target beside Imitation-BT+ at the task's headline leaf limit, and the best point
    of any leaf limit that meets the node bar (mean over seeds)."""
    plus = table[table["method"] == PLUS]
    rows = []
    for task in targets():
        target = task.front_target
        assert target is not None
        for algo in target.experts:
            runs = plus[(plus["task"] == task.name) & (plus["expert"] == algo)]
            limit = headline.get(task.name) or task.budget.max_leaf_nodes
            at = runs[runs["max_leaf_nodes"] == limit]
            row: dict[str, Any] = {"task": task.name, "expert": algo,
                                   "target": target.describe(),
                                   "leaf_limit": limit, "seeds": len(at)}
            if at.empty:
                rows.append({**row, "verdict": "not measured"})
                continue
            retention, nodes = at["retention_norm"].mean(), at["bt_nodes"].mean()
            row.update({"retention_norm": retention, "retention_min": at["retention_norm"].min(),
                        "bt_nodes": nodes})
            if target.min_retention is None or target.max_bt_nodes is None:
                rows.append({**row, "verdict": "measured"})
                continue
            met = retention >= target.min_retention and nodes <= target.max_bt_nodes
            row["verdict"] = "met" if met else "missed"
            means = runs.groupby("max_leaf_nodes")[["retention_norm", "bt_nodes"]].mean()
            fits = means[means["bt_nodes"] <= target.max_bt_nodes]
            if not fits.empty:
                best = fits.sort_values("retention_norm").iloc[-1]
                row.update({"best_fitting_limit": int(best.name),
                            "best_fitting_retention": best["retention_norm"],
                            "best_fitting_nodes": best["bt_nodes"]})
            rows.append(row)
    return pd.DataFrame(rows)


def stage_seconds(table: pd.DataFrame) -> pd.DataFrame:
    """CPU time per stage, summed over the front's runs (each run is one process, one core).

    Imitation-BT+'s distillation (its four source runs) is counted once per task, expert and
    seed, however many leaf limits refine it.
    """
    rows = []
    for method, group in table.groupby("method", sort=False):
        sources = group.drop_duplicates(["task", "expert", "seed"]) if method == PLUS else group
        rows.append({"method": method, "runs": len(group),
                     "distill_hours": sources["distill_seconds"].sum() / 3600,
                     "refine_hours": group["refine_seconds"].sum() / 3600,
                     "refine_episodes": int(group["refine_episodes"].sum()),
                     "refine_steps": int(group["refine_steps"].sum())})
    return pd.DataFrame(rows)
