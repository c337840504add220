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
from ibt.policies import CompiledTree
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
        compiled = CompiledTree(tree)
        spec = get_task(task)
        result = rollout(spec, lambda obs: compiled.predict(spec.features(obs)),
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
    row = {"task": cell.task, "expert": cell.algo, "method": cell.method, "seed": cell.seed,
           **{k: v for k, v in cell.overrides},
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
