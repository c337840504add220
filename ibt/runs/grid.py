"""Grids of distillation runs (task x expert x method x seed), spread over cores or a cluster.

A :class:`Cell` is one run; :func:`run_cell` distils (cached), evaluates the chosen tree on the
fixed final-evaluation episodes (cached) and returns one results row. :func:`run_grid` maps
cells through joblib: local processes by default, a Dask distributed cluster when a scheduler
address is given (``scheduler=`` or ``IBT_DASK_SCHEDULER``). Every cell is deterministic in its
seed, so where it runs never changes its row.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from joblib import Parallel, delayed, parallel_config
from tqdm import tqdm

from ibt.cache.store import load_or_compute, tree_digest
from ibt.distill.loop import METHODS
from ibt.distill.schedules import Schedule
from ibt.engine import measure
from ibt.engine.keys import bt_digest
from ibt.evaluate.rollouts import retention_norm, retention_raw
from ibt.experts.expert import expert_path, load_expert
from ibt.experts.training import expert_statuses
from ibt.profiles import Config
from ibt.report.stats import bootstrap_ci, node_table, retention_table, summarise  # noqa: F401
from ibt.runs.steps import distill_cached
from ibt.synth.registry import SYNTHESISERS
from ibt.tasks.catalogue import get_task
from ibt.tasks.task import Task


@dataclass(frozen=True)
class Cell:
    """One distillation run of the grid; ``overrides`` go to the distillation config.

    The cell carries its :class:`Task` whole (resolved when the grid is made), so a task
    registered at run time works in worker processes too."""

    task: Task
    algo: str
    method: str
    seed: int
    overrides: tuple[tuple[str, Any], ...] = field(default_factory=tuple)

    def label(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in self.overrides)
        return f"{self.task.name}/{self.algo}/{self.method}/s{self.seed}" + (f"[{extra}]" if extra
                                                                          else "")


def grid(tasks: Iterable[str | Task], algos: Iterable[str], methods: Iterable[str] = tuple(METHODS),
         seeds: Iterable[int] = (0, 1, 2), **overrides: Any) -> list[Cell]:
    """The full cross product as cells (every task x algo x method x seed)."""
    extra = tuple(sorted(overrides.items()))
    resolved = [get_task(t) for t in tasks]  # the boundary: names become tasks once, here
    return [Cell(t, a, m, s, extra) for t in resolved for a in algos
            for m in methods for s in seeds]


#: Seeds per cell of the paper grid: 5 (a 95 % bootstrap CI needs them, see ibt.report.stats),
#: fewer where a task's catalogue entry says so (``Task.paper_seeds``: 3 on highway)
PAPER_SEEDS = 5


def seed_budget(cells: Iterable[Cell]) -> list[Cell]:
    """The cells within their task's seed count (``Task.paper_seeds``)."""
    return [c for c in cells if c.seed < c.task.paper_seeds]


def uncached(cfg: Config, cells: Iterable[Cell]) -> list[Cell]:
    """The cells whose distillation is not in the cache yet (what ``pending`` may list)."""
    from ibt.cache.store import is_cached
    from ibt.runs.steps import distill_params

    return [c for c in cells if not is_cached("distill", distill_params(
        cfg, c.task, c.algo, c.method, c.seed, **dict(c.overrides)), cache_dir=cfg.cache_dir)]


def expert_evaluation(cfg: Config, task: str | Task, algo: str) -> dict[str, float]:
    """:func:`ibt.engine.measure.expert_evaluation` of a task named or given (the notebooks')."""
    return measure.expert_evaluation(cfg, get_task(task), algo)


def evaluate_tree(cfg: Config, task: str | Task, tree: Any) -> dict[str, float]:
    """:func:`ibt.engine.measure.evaluate_tree` of a task named or given (the notebooks')."""
    return measure.evaluate_tree(cfg, get_task(task), tree)


def evaluate_bt(cfg: Config, task: str | Task, bt: Any) -> dict[str, float]:
    """:func:`ibt.engine.measure.evaluate_bt` of a task named or given (the notebooks')."""
    return measure.evaluate_bt(cfg, get_task(task), bt)


def run_cell(cfg: Config, cell: Cell) -> dict[str, Any]:
    """Distil and evaluate one cell; one row of ``data/results/distillation.csv``."""
    run = distill_cached(cfg, cell.task, cell.algo, cell.method, cell.seed,
                         **dict(cell.overrides))
    tree = run.best_tree
    evaluation = evaluate_tree(cfg, cell.task, tree)
    expert = expert_evaluation(cfg, cell.task, cell.algo)
    random_return = cell.task.random_return(cfg.experts_dir)
    schedule = Schedule(**run.config["schedule"])
    row = {"task": cell.task.name, "expert": cell.algo, "method": cell.method,
           "seed": cell.seed,
           "schedule": schedule.label,
           **{k: v for k, v in cell.overrides if k != "schedule"},
           "mean_return": evaluation["mean_return"], "std_return": evaluation["std_return"],
           "expert_return": expert["mean_return"], "random_return": random_return,
           "retention_raw": retention_raw(evaluation["mean_return"], expert["mean_return"]),
           "retention_norm": retention_norm(evaluation["mean_return"], expert["mean_return"],
                                            random_return),
           "nodes": int(tree.tree_.node_count), "leaves": int(tree.get_n_leaves()),
           "best_iteration": run.best_index, "expert_labels": run.expert_labels,
           # the distillation's own recorded time: stable across cache hits, unlike this call's
           "wall_seconds": round(run.wall_seconds, 2),
           "expert_status": expert_statuses(cfg.experts_dir).get((cell.task.name, cell.algo),
                                                                  "ok")}
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


def available(cells: Iterable[Cell], experts_dir: Path | None = None) -> list[Cell]:
    """The cells whose expert checkpoint is committed (the others are reported as missing)."""
    return [c for c in cells if expert_path(c.task, c.algo, experts_dir).exists()]


def write_results(cfg: Config, frame: pd.DataFrame, name: str, **facts: Any) -> Path | None:
    """``data/results/<name>.csv`` plus ``<name>.manifest.json`` (profile's data dir).

    The manifest records the grid's facts (cells, total and summed wall time, machine,
    versions) beside the table; not the git commit, which would change it on every commit.
    """
    import json
    import platform

    from ibt.cache.store import package_versions
    from ibt.files import atomic_write_csv, atomic_write_text

    target = cfg.data_dir / "results" / f"{name}.csv"
    atomic_write_csv(target, frame)
    manifest = {"rows": len(frame), "profile": cfg.profile,
                "summed_cell_seconds": round(float(frame.get("wall_seconds",
                                                             pd.Series([0.0])).sum()), 1),
                "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                "versions": package_versions(), **facts}
    atomic_write_text(target.with_suffix(".manifest.json"),
                      json.dumps(manifest, indent=1, sort_keys=True, default=str) + "\n")
    return target


def seed_best(results: pd.DataFrame, task: str, algo: str, method: str) -> int:
    """``task``: the task's name, as in the results table."""
    """The seed whose run scored best on the final episodes (fewer nodes break ties)."""
    rows = results[(results.task == task) & (results.expert == algo) & (results.method == method)]
    if rows.empty:
        raise LookupError(f"no {method} runs for {task}/{algo} in the results")
    best = rows.sort_values(["mean_return", "nodes", "seed"], ascending=[False, True, True])
    return int(best.iloc[0]["seed"])


def bt_methods() -> tuple[str, ...]:
    """The BT synthesisers of the grid: every registered one, in registry order."""
    return tuple(SYNTHESISERS)


BT_METHODS = bt_methods()  # the built-in four (imitation-bt, the two baselines, decision-list)


def synthesize_run(cfg: Config, task: str | Task, algo: str, method: str, seed: int,
                   source_method: str, **overrides: Any) -> dict[str, Any]:
    """One BT from the best tree of one distillation run, verified against it (cached).

    Returns ``{"row": structure facts, "bt": BehaviorTree}``; a BT that disagrees with its tree
    raises :class:`ibt.synth.imitation.NotEquivalentError` and nothing is cached or written.
    """
    from ibt.engine.synthesis import synthesised

    spec = get_task(task)
    tree = distill_cached(cfg, spec, algo, source_method, seed, **overrides).best_tree
    return synthesised(cfg, spec, algo, method, seed, source_method, tree, analysis=True)


def executors_agree(cfg: Config, task: str | Task, bt: Any, tree: Any, n_states: int = 100_000
                    ) -> dict[str, Any]:
    """Do py_trees, the NumPy and compiled-Python executors and the sklearn tree decide alike
    on ``n_states`` random states of the task's box? (cached: py_trees ticks ~10^4 states/s)."""
    from ibt.evaluate import speed

    spec = get_task(task)
    params = {"task": spec.name, "n_states": n_states, "tree": tree_digest(tree),
              "bt": bt_digest(bt)}

    def compute() -> dict[str, Any]:
        states = spec.sample_features(n_states, np.random.default_rng(0))
        return {"task": spec.name, "states": n_states, "bt_nodes": bt.node_count,
                "agree": speed.executors_agree(bt, tree, states)}

    return load_or_compute("executors", params, compute, cache_dir=cfg.cache_dir, codec="json",
                           refresh=cfg.refresh)


def speed_benchmark(cfg: Config, task: str | Task, algo: str, seed: int) -> pd.DataFrame:
    """Decisions per second of every executor (:func:`ibt.evaluate.speed.benchmark`) on the
    Imitation-BT BT of one grid run, measured once per machine and cached: a rerun of
    ``make figures`` shows the same measurement, ``make reproduce`` measures again."""
    import platform

    from ibt.evaluate import speed
    from ibt.synth.imitation import imitation_bt

    spec = get_task(task)
    tree = distill_cached(cfg, spec, algo, "imitation-bt", seed).best_tree
    bt = imitation_bt(tree, spec).bt
    params = {"task": spec.name, "algo": algo, "seed": seed, "tree": tree_digest(tree),
              "bt": bt_digest(bt), "machine": f"{platform.machine()} {platform.processor()}",
              "cores": os.cpu_count()}

    def compute() -> list[dict[str, Any]]:
        states = spec.sample_features(100_000, np.random.default_rng(0))
        expert = load_expert(spec, algo, expert_path(spec, algo, cfg.experts_dir))
        rates = speed.benchmark(bt, tree, expert, states, spec.observations(states))
        return rates.to_dict("records")

    rows = load_or_compute("speed", params, compute, cache_dir=cfg.cache_dir, codec="json",
                           refresh=cfg.refresh)
    # the columns in their own order (a JSON payload sorts its keys)
    return pd.DataFrame(rows)[["executor", "mode", "decisions_per_second"]]


def synthesize_grid(cfg: Config, results: pd.DataFrame, baseline_source: str = "bc"
                    ) -> pd.DataFrame:
    """``data/results/synthesis.csv``: one BT per (task, expert, BT method, source seed).

    Imitation-BT (and the decision-list BT, beyond the paper: :mod:`ibt.synth.decision_list`) is
    synthesised from each Imitation-BT run's best tree; BT-Espresso and
    RE:BT-Espresso from each ``baseline_source`` run's tree (offline demonstrations, as in
    their papers). Every BT is verified to decide exactly as its tree, so its episodes are the
    tree's: performance columns come from the tree's final evaluation (``evaluated`` says
    so), except for the seed-best BT of each method, which is rolled out in the environment
    itself (``matches_tree`` checks that the returns agree) and written to ``data/trees/``.
    """
    from ibt.runs.steps import save_tree

    sources = {name: baseline_source if s.source == "baseline" else s.source
               for name, s in SYNTHESISERS.items()}
    pairs = list(results[["task", "expert"]].drop_duplicates().itertuples(index=False))
    statuses = expert_statuses(cfg.experts_dir)
    rows = []
    for task, algo in tqdm(pairs, desc="synthesis", disable=not cfg.progress):
        spec = get_task(task)
        expert_return = expert_evaluation(cfg, spec, algo)["mean_return"]
        random_return = spec.random_return(cfg.experts_dir)
        for method in bt_methods():
            source = sources[method]
            runs = results[(results.task == task) & (results.expert == algo)
                           & (results.method == source)]
            if runs.empty:
                continue
            best_seed = seed_best(results, task, algo, source)
            for source_row in runs.itertuples(index=False):
                made = synthesize_run(cfg, spec, algo, method, int(source_row.seed), source)
                row = {**made["row"], "seed_best": int(source_row.seed) == best_seed}
                row["tree_splits"] = (int(row["tree_nodes"]) - 1) // 2  # binary: 2 s + 1 nodes
                perf = {"mean_return": source_row.mean_return,
                        "std_return": source_row.std_return}
                row["evaluated"] = "source tree (verified equivalent)"
                if row["seed_best"]:
                    perf = evaluate_bt(cfg, spec, made["bt"])
                    row["evaluated"] = "BT rollout"
                    row["matches_tree"] = bool(
                        np.isclose(perf["mean_return"], source_row.mean_return))
                    save_tree(cfg, made["bt"], spec, algo, method)
                row.update({k: v for k, v in perf.items() if k.endswith("_rate")
                            or k in ("delivered",)})
                row.update({"mean_return": perf["mean_return"], "std_return": perf["std_return"],
                            "expert_return": expert_return, "random_return": random_return,
                            "retention_raw": retention_raw(perf["mean_return"], expert_return),
                            "retention_norm": retention_norm(perf["mean_return"], expert_return,
                                                             random_return),
                            "expert_status": statuses.get((task, algo), "ok")})
                rows.append(row)
    return pd.DataFrame(rows)
