"""The steps notebooks call: cached distillation, synthesis to files, comparison tables.

Each function does one step of the data flow (expert -> tree -> BT -> evaluation) under a
:class:`ibt.profiles.Config`, reading heavy results from the cache when they are there.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pandas as pd

from ibt.bt.json_io import save_json
from ibt.bt.model import BehaviorTree
from ibt.distill.loop import Distillation, DistillConfig
from ibt.engine import budgets
from ibt.engine.agent import committed_agent
from ibt.engine.distil import distill_key, distillation
from ibt.engine.measure import final_metrics
from ibt.evaluate.rollouts import (
    retention_norm,
    retention_raw,
)
from ibt.experts import expert as experts
from ibt.experts.expert import Expert
from ibt.profiles import Config
from ibt.tasks.catalogue import get_task
from ibt.tasks.task import Task


def distill_config(cfg: Config, task: str | Task, method: str = "imitation-bt",
                   **overrides: Any) -> DistillConfig:
    """The task's distillation settings scaled to the profile's budgets
    (:func:`ibt.engine.budgets.distill_config`)."""
    return budgets.distill_config(cfg, get_task(task), method, **overrides)


def distill_params(cfg: Config, task: str | Task, algo: str, method: str = "imitation-bt",
                   seed: int = 0, **overrides: Any) -> dict[str, Any]:
    """The cache parameters of one distillation run (see :func:`distill_cached`)."""
    agent = committed_agent(get_task(task), algo, cfg.experts_dir)
    return distill_key(cfg, agent, seed, "axis", method, **overrides)[1]


def distill_cached(cfg: Config, task: str | Task, algo: str, method: str = "imitation-bt",
                   seed: int = 0, **overrides: Any) -> Distillation:
    """A distillation run of the committed expert (the engine's stage,
    :func:`ibt.engine.distil.distillation`), from the cache when the same expert,
    settings and seed ran before: the key holds the checkpoint's digest, so a retrained expert
    is a cache miss."""
    agent = committed_agent(get_task(task), algo, cfg.experts_dir)
    return distillation(cfg, agent, seed, "axis", method, **overrides)


def load_expert(task: str | Task, algo: str, path: str | Path | None = None) -> Expert:
    """The notebooks' expert loader (``ibt.load_expert``): a task name or :class:`Task`,
    resolved here at the boundary (:func:`ibt.experts.expert.load_expert` takes the Task)."""
    return experts.load_expert(get_task(task), algo, path)


def iterations_frame(run: Distillation) -> pd.DataFrame:
    """One row per iteration, with the chosen tree marked."""
    frame = pd.DataFrame(run.iterations)
    frame["best"] = frame["iteration"] == run.best_index
    return frame


def tree_path(cfg: Config, task: str | Task, algo: str, method: str) -> Path:
    return cfg.data_dir / "trees" / get_task(task).name / algo / f"{method}.json"


def save_tree(cfg: Config, bt: BehaviorTree, task: str | Task, algo: str, method: str) -> Path:
    """Write ``data/trees/<task>/<algo>/<method>.json`` (under the profile's data dir)."""
    return save_json(bt, tree_path(cfg, task, algo, method))


def compare_policies(cfg: Config, task: str | Task, policies: dict[str, Any],
                     reference: str = "expert",
                     random_return: float | None = None) -> pd.DataFrame:
    """Return statistics of each policy over the profile's final-evaluation episodes.

    Retention is relative to the policy named ``reference`` (measured here, on the same
    episodes); the random-normalised retention needs ``random_return``.
    """
    task_obj = get_task(task)
    if reference not in policies:
        raise KeyError(f"reference policy {reference!r} is not among {list(policies)}")
    rows = []
    for name, policy in policies.items():
        row = {"policy": name, "episodes": cfg.final_episodes,
               **final_metrics(task_obj, policy.act, cfg.final_episodes)}
        row["nodes"] = _nodes(policy)
        rows.append(row)
    frame = pd.DataFrame(rows).set_index("policy")
    expert = frame.loc[reference, "mean_return"]
    frame["retention_raw_%"] = [retention_raw(r, expert) for r in frame["mean_return"]]
    if random_return is not None:
        frame["retention_norm_%"] = [retention_norm(r, expert, random_return)
                                     for r in frame["mean_return"]]
    return frame


def provenance() -> dict[str, str]:
    """Package versions and the machine, for the last cell of every notebook (no git commit:
    it changes on every commit, and a committed notebook is its own commit's)."""
    import platform

    from ibt.cache.store import package_versions

    return {"python": platform.python_version(),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores", **package_versions()}


def _nodes(policy: Any) -> float:
    if hasattr(policy, "bt"):
        return policy.bt.node_count
    if hasattr(policy, "tree"):
        return policy.tree.tree_.node_count
    return float("nan")
