"""Grids of distillation runs (task x expert x method x seed), spread over cores or a cluster.

A :class:`Cell` is one run; :func:`run_cell` distils (cached), evaluates the chosen tree on the
fixed final-evaluation episodes (cached) and returns one results row. :func:`run_grid` maps
cells through joblib: local processes by default, a Dask distributed cluster when a scheduler
address is given (``scheduler=`` or ``IBT_DASK_SCHEDULER``). Every cell is deterministic in its
seed, so where it runs never changes its row.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from joblib import Parallel, delayed, parallel_config
from tqdm import tqdm

from ibt.artifacts import file_digest, load_or_compute
from ibt.config import Config
from ibt.distill import METHODS, _signature
from ibt.evaluate import episode_metrics, final_seeds, retention_norm, retention_raw, rollout
from ibt.experts import expert_path, load_expert
from ibt.pipeline import distill_cached
from ibt.policies import TreePolicy
from ibt.schedules import Schedule
from ibt.tasks import get_task


@dataclass(frozen=True)
class Cell:
    """One distillation run of the grid; ``overrides`` go to the distillation config."""

    task: str
    algo: str
    method: str
    seed: int
    overrides: tuple[tuple[str, Any], ...] = field(default_factory=tuple)

    def label(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in self.overrides)
        return f"{self.task}/{self.algo}/{self.method}/s{self.seed}" + (f"[{extra}]" if extra
                                                                          else "")


def grid(tasks: Iterable[str], algos: Iterable[str], methods: Iterable[str] = tuple(METHODS),
         seeds: Iterable[int] = (0, 1, 2), **overrides: Any) -> list[Cell]:
    """The full cross product as cells (every task x algo x method x seed)."""
    extra = tuple(sorted(overrides.items()))
    return [Cell(get_task(t).name, a, m, s, extra) for t in tasks for a in algos
            for m in methods for s in seeds]


def expert_evaluation(cfg: Config, task: str, algo: str) -> dict[str, float]:
    """The expert's return on the profile's final-evaluation episodes (cached)."""
    params = {"task": task, "algo": algo, "episodes": cfg.final_episodes,
              "expert_sha256": file_digest(expert_path(task, algo))}

    def compute() -> dict[str, float]:
        result = rollout(task, load_expert(task, algo).act, final_seeds(cfg.final_episodes))
        return {"mean_return": result.mean, "std_return": result.std}

    return load_or_compute("expert-eval", params, compute, cache_dir=cfg.cache_dir,
                           codec="json", refresh=cfg.refresh)


def evaluate_tree(cfg: Config, task: str, tree: Any) -> dict[str, float]:
    """A decision tree's final evaluation (cached on the tree's exact structure)."""
    params = {"task": task, "episodes": cfg.final_episodes,
              "tree": _signature(tree).hex()}

    def compute() -> dict[str, float]:
        spec = get_task(task)
        result = rollout(spec, TreePolicy(spec, tree).act,
                         final_seeds(cfg.final_episodes))
        return {"mean_return": result.mean, "std_return": result.std,
                **episode_metrics(spec, result)}

    return load_or_compute("tree-eval", params, compute, cache_dir=cfg.cache_dir, codec="json",
                           refresh=cfg.refresh)


def run_cell(cfg: Config, cell: Cell) -> dict[str, Any]:
    """Distil and evaluate one cell; one row of ``data/results/distillation.csv``."""
    start = time.perf_counter()
    run = distill_cached(cfg, cell.task, cell.algo, cell.method, cell.seed,
                         **dict(cell.overrides))
    tree = run.best_tree
    evaluation = evaluate_tree(cfg, cell.task, tree)
    expert = expert_evaluation(cfg, cell.task, cell.algo)
    random_return = get_task(cell.task).random_return()
    schedule = Schedule(**run.config["schedule"])
    row = {"task": cell.task, "expert": cell.algo, "method": cell.method, "seed": cell.seed,
           "schedule": schedule.label,
           **{k: v for k, v in cell.overrides if k != "schedule"},
           "mean_return": evaluation["mean_return"], "std_return": evaluation["std_return"],
           "expert_return": expert["mean_return"], "random_return": random_return,
           "retention_raw": retention_raw(evaluation["mean_return"], expert["mean_return"]),
           "retention_norm": retention_norm(evaluation["mean_return"], expert["mean_return"],
                                            random_return),
           "nodes": int(tree.tree_.node_count), "leaves": int(tree.get_n_leaves()),
           "best_iteration": run.best_index, "expert_labels": run.expert_labels,
           "distill_seconds": round(run.wall_seconds, 2),
           "wall_seconds": round(time.perf_counter() - start, 2)}
    row.update({k: v for k, v in evaluation.items() if k.endswith("_rate")})
    return row


def _dask_client(scheduler: str | None):
    address = scheduler or os.environ.get("IBT_DASK_SCHEDULER")
    if not address:
        return None
    from dask.distributed import Client

    return Client(address)


def run_grid(cfg: Config, cells: Sequence[Cell], *, n_jobs: int | None = None,
             scheduler: str | None = None) -> pd.DataFrame:
    """Run every cell (cached ones are instant) and return the rows in cell order.

    ``scheduler``/``IBT_DASK_SCHEDULER``: the address of a Dask distributed scheduler; the same
    joblib call then ships cells to the cluster's workers, which must see this repository.
    """
    n_jobs = n_jobs or cfg.n_jobs
    client = _dask_client(scheduler)
    backend = {"backend": "dask"} if client is not None else {"backend": "loky",
                                                              "n_jobs": n_jobs}
    quiet = Config(**{**asdict(cfg), "progress": False})
    try:
        with parallel_config(**backend):
            jobs = Parallel(return_as="generator", n_jobs=-1 if client else n_jobs)(
                delayed(run_cell)(quiet, cell) for cell in cells)
            rows = list(tqdm(jobs, total=len(cells), desc="grid", disable=not cfg.progress))
    finally:
        if client is not None:
            client.close()
    return pd.DataFrame(rows)


def available(cells: Iterable[Cell]) -> list[Cell]:
    """The cells whose expert checkpoint is committed (the others are reported as missing)."""
    return [c for c in cells if expert_path(c.task, c.algo).exists()]


def write_results(cfg: Config, frame: pd.DataFrame, name: str, **facts: Any) -> Path | None:
    """``data/results/<name>.csv`` plus ``<name>.manifest.json`` (profile's data dir).

    The manifest records the grid's facts (cells, total and summed wall time, machine,
    versions) beside the table.
    """
    import json
    import platform

    from ibt.artifacts import atomic_write_csv, atomic_write_text, git_sha, package_versions

    target = cfg.data_dir / "results" / f"{name}.csv"
    atomic_write_csv(target, frame)
    manifest = {"rows": len(frame), "profile": cfg.profile,
                "summed_cell_seconds": round(float(frame.get("wall_seconds",
                                                             pd.Series([0.0])).sum()), 1),
                "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                "git_sha": git_sha(), "versions": package_versions(), **facts}
    atomic_write_text(target.with_suffix(".manifest.json"),
                      json.dumps(manifest, indent=1, sort_keys=True, default=str) + "\n")
    return target


def bootstrap_ci(values: Sequence[float], n_boot: int = 2000, level: float = 0.95,
                 seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean."""
    values = np.asarray(values, dtype=float)
    if len(values) < 2:
        return (float(values.mean()), float(values.mean())) if len(values) else (np.nan, np.nan)
    rng = np.random.default_rng(seed)
    means = rng.choice(values, size=(n_boot, len(values)), replace=True).mean(axis=1)
    alpha = (1 - level) / 2
    return float(np.quantile(means, alpha)), float(np.quantile(means, 1 - alpha))


def summarise(results: pd.DataFrame, value: str = "retention_norm",
              by: Sequence[str] = ("task", "expert", "method")) -> pd.DataFrame:
    """Mean and 95 % bootstrap CI of ``value`` per group."""
    rows = []
    for key, group in results.groupby(list(by), sort=False):
        low, high = bootstrap_ci(group[value].to_numpy())
        rows.append({**dict(zip(by, key, strict=True)), "n": len(group),
                     value: group[value].mean(), "ci_low": low, "ci_high": high,
                     "nodes": group["nodes"].mean() if "nodes" in group else np.nan})
    return pd.DataFrame(rows)


def seed_best(results: pd.DataFrame, task: str, algo: str, method: str) -> int:
    """The seed whose run scored best on the final episodes (fewer nodes break ties)."""
    rows = results[(results.task == task) & (results.expert == algo) & (results.method == method)]
    if rows.empty:
        raise LookupError(f"no {method} runs for {task}/{algo} in the results")
    best = rows.sort_values(["mean_return", "nodes", "seed"], ascending=[False, True, True])
    return int(best.iloc[0]["seed"])


def synthesize_cell(cfg: Config, results: pd.DataFrame, task: str, algo: str,
                    baseline_source: str = "bc") -> list[dict[str, Any]]:
    """Imitation-BT from the seed-best Imitation-BT tree, the two baselines from the seed-best
    ``baseline_source`` tree; every BT verified, written to ``data/trees/`` and evaluated."""
    from ibt.baselines import bt_espresso, re_bt_espresso
    from ibt.pipeline import save_tree
    from ibt.policies import BTPolicy
    from ibt.synthesis import DEFAULT_STRATEGIES, imitation_bt, verify

    spec = get_task(task)
    expert = expert_evaluation(cfg, task, algo)
    random_return = spec.random_return()
    rows = []
    ibt_seed = seed_best(results, task, algo, "imitation-bt")
    ibt_tree = distill_cached(cfg, task, algo, "imitation-bt", ibt_seed).best_tree
    base_seed = seed_best(results, task, algo, baseline_source)
    base_tree = distill_cached(cfg, task, algo, baseline_source, base_seed).best_tree
    strategies = {s: imitation_bt(ibt_tree, spec, default_strategy=s) for s in DEFAULT_STRATEGIES}
    with_dc = imitation_bt(ibt_tree, spec, dont_cares=True)
    made = [("imitation-bt", ibt_seed, "imitation-bt", ibt_tree, strategies["max_complexity"]),
            ("bt-espresso", base_seed, baseline_source, base_tree, bt_espresso(base_tree, spec)),
            ("re-bt-espresso", base_seed, baseline_source, base_tree,
             re_bt_espresso(base_tree, spec))]
    for method, seed, source, tree, result in made:
        checked = verify(result.bt, tree, spec)
        save_tree(cfg, result.bt, task, algo, method)
        run = rollout(spec, BTPolicy(spec, result.bt).act, final_seeds(cfg.final_episodes))
        row = {"task": task, "expert": algo, "method": method, "source_method": source,
               "source_seed": seed, "nodes": result.bt.node_count,
               "tree_nodes": int(tree.tree_.node_count),
               "conditions": result.bt.node_types()["condition"],
               **{f"n_{k}": v for k, v in result.bt.node_types().items()},
               "default_action": (spec.action_names[result.default_action]
                                  if result.default_action is not None else ""),
               "default_strategy": result.default_strategy or "",
               "equivalent": True, "states_checked": checked,
               "mean_return": run.mean, "std_return": run.std,
               "retention_raw": retention_raw(run.mean, expert["mean_return"]),
               "retention_norm": retention_norm(run.mean, expert["mean_return"], random_return)}
        if method == "imitation-bt":
            row.update({f"nodes_{s}": r.bt.node_count for s, r in strategies.items()})
            row["nodes_dont_cares"] = with_dc.bt.node_count
        rows.append(row)
    return rows
