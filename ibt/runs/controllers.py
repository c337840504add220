"""The controllers study: BTs that steer, distilled from agents, beside hand-written controllers.

For each ``Box`` task with a committed agent, a controller tree (:mod:`ibt.distill.controller`)
is distilled at a few leaf limits and seeds, refined by return (:mod:`ibt.refine.controller`),
turned into a verified BT of ``ScriptCondition`` tests and linear ``Script`` commands
(:mod:`ibt.synth.controller`), and measured on the project's final episodes beside Gymnasium's
hand-written LunarLander controller and DSP's published formulas
(:mod:`ibt.runs.reference_controllers`), on the same episodes.

Each stage is cached (kinds ``controller-distil`` and ``controller-refine``; returns under the
kind ``returns``), keyed by the task, the agent's digest, the seed and the settings, so
``make figures`` reads every number from ``data/cache/``. Budgets are in episodes, per task
(:data:`BUDGETS`); the ``smoke`` profile shrinks them to seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ibt.cache.store import load_or_compute
from ibt.distill.controller import ControllerArrays, ControllerConfig
from ibt.evaluate.rollouts import final_seeds, rollout
from ibt.profiles import Config
from ibt.tasks.settings import RefineConfig
from ibt.tasks.task import Task

LEARNER = "controller"


@dataclass(frozen=True)
class ControllerBudget:
    """One task's controller settings: the loop's, refinement's and the study's grid."""

    distil: ControllerConfig
    refine: RefineConfig
    leaves: tuple[int, ...]
    seeds: tuple[int, ...] = (0, 1, 2)
    tolerance: float = 0.5  # return (task units) rounding the constants may cost


#: per task: chosen before the study's results, from the tasks' episode lengths and one
#: refinement trial each on this machine (MountainCarContinuous, 2 leaves: 93.3 -> 97.8 on the
#: held-out episodes in 3,000 episodes; Pendulum, 3 leaves: -448 -> -170 in 6,000, whose noisy
#: generations of 8 episodes led to 16 here)
BUDGETS: dict[str, ControllerBudget] = {
    "MountainCarContinuous-v0": ControllerBudget(
        ControllerConfig(max_leaves=2, n_iterations=8, labels_per_iteration=3000),
        RefineConfig(stages=("cma", "cma"), episodes=8_000, cma_generations=40,
                     cma_episodes=16, selection_episodes=100), leaves=(1, 2), tolerance=0.2),
    "Pendulum-v1": ControllerBudget(
        ControllerConfig(max_leaves=4, n_iterations=8, labels_per_iteration=3000),
        RefineConfig(stages=("cma", "cma"), episodes=12_000, cma_generations=40,
                     cma_episodes=16, selection_episodes=100), leaves=(2, 3, 4), tolerance=2.0),
    "LunarLanderContinuous-v3": ControllerBudget(
        ControllerConfig(max_leaves=8, n_iterations=10, labels_per_iteration=4000),
        RefineConfig(stages=("cma", "cma"), episodes=12_000, cma_generations=60,
                     cma_episodes=8, selection_episodes=100), leaves=(4, 8), tolerance=2.0),
}


def budget_of(task: Task, cfg: Config) -> ControllerBudget:
    """The task's budget under ``cfg``'s profile (``smoke``: a few episodes, one seed)."""
    if task.name not in BUDGETS:
        raise ValueError(f"no controller budget for {task.name}; the study runs "
                         f"{', '.join(BUDGETS)}")
    budget = BUDGETS[task.name]
    if cfg.profile != "smoke":
        return budget
    return replace(budget, distil=replace(budget.distil, n_iterations=2,
                                          labels_per_iteration=300, selection_episodes=2,
                                          eval_envs=2),
                   refine=replace(budget.refine, stages=("cma",), episodes=40,
                                  cma_generations=1, cma_episodes=2, selection_episodes=2,
                                  n_envs=8),
                   leaves=budget.leaves[:1], seeds=(0,))


def _agent(task: Task, algo: str, cfg: Config) -> Any:
    from ibt.engine.agent import committed_agent

    return committed_agent(task, algo, cfg.experts_dir)


def distilled(task: Task, algo: str, leaves: int, seed: int, cfg: Config) -> ControllerArrays:
    """The controller tree distilled from the committed agent (cached)."""
    from ibt.distill.controller import distill_controller

    agent = _agent(task, algo, cfg)
    config = replace(budget_of(task, cfg).distil, max_leaves=leaves)
    params = {"task": task.key, "algo": algo, "expert_sha256": agent.digest, "seed": seed,
              "config": config.as_params()}

    def compute() -> dict[str, Any]:
        record = distill_controller(task, agent.load(), config, seed, progress=cfg.progress)
        return {"tree": record.best_tree.to_doc(), "iterations": record.iterations,
                "wall_seconds": record.wall_seconds}

    doc = load_or_compute("controller-distil", params, compute, cache_dir=cfg.cache_dir,
                          refresh=cfg.refresh)
    return ControllerArrays.from_doc(doc["tree"])


def refined(task: Task, algo: str, leaves: int, seed: int, cfg: Config) -> dict[str, Any]:
    """The refinement record of the distilled tree (cached): candidates, stages, choice."""
    from ibt.refine.controller import refine_controller

    source = distilled(task, algo, leaves, seed, cfg)
    budget = budget_of(task, cfg)
    params = {"task": task.key, "source": source.digest(), "seed": seed,
              "config": budget.refine.as_params(), "tolerance": budget.tolerance}

    def compute() -> dict[str, Any]:
        return refine_controller(source, task, budget.refine, seed, tolerance=budget.tolerance,
                                 progress=cfg.progress).to_doc()

    return load_or_compute("controller-refine", params, compute, cache_dir=cfg.cache_dir,
                           refresh=cfg.refresh)


def final_returns(task: Task, what: dict[str, Any], act: Any, episodes: int, cfg: Config
                  ) -> list[float]:
    """A policy's returns on the first ``episodes`` final episodes (cached as ``returns``)."""
    seeds = final_seeds(episodes)
    params = {"task": task.key, "episodes": len(seeds), "first_seed": seeds[0], **what}

    def compute() -> dict[str, Any]:
        done = rollout(task, act, seeds, n_envs=32)
        return {"returns": [float(r) for r in done.returns],
                "lengths": [int(n) for n in done.lengths]}

    doc = load_or_compute("returns", params, compute, cache_dir=cfg.cache_dir,
                          refresh=cfg.refresh)
    return list(doc["returns"])


def verified(task: Task, algo: str, leaves: int, seed: int, cfg: Config
             ) -> tuple[dict[str, Any], ControllerArrays, Any]:
    """One run's refinement record, its chosen tree and that tree's verified BT
    (:class:`ibt.synth.controller.ControllerBT`, checked on the states of 4 final episodes,
    random states and both sides of every axis test)."""
    from ibt.synth.controller import check_states, controller_bt

    record = refined(task, algo, leaves, seed, cfg)
    tree = ControllerArrays.from_doc(record["candidates"][record["best_index"]])
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    visited: list[np.ndarray] = []

    def act(obs: np.ndarray) -> np.ndarray:
        x = task.features(obs)
        visited.append(x)
        return np.clip(tree.decide(x), low, high).astype(np.float32)

    rollout(task, act, final_seeds(4), n_envs=4)  # states to check the BT on
    built = controller_bt(tree, task, check_states(tree, task, np.concatenate(visited),
                                                   seed=seed))
    return record, tree, built


def controller_row(task: Task, algo: str, leaves: int, seed: int, cfg: Config,
                   episodes: int) -> tuple[dict[str, Any], Any]:
    """One refined controller's row and its verified BT, measured on ``episodes`` final
    episodes."""
    from ibt.engine.stages import bt_digest
    from ibt.synth.commands import CommandBTPolicy

    record, tree, built = verified(task, algo, leaves, seed, cfg)
    policy = CommandBTPolicy(task, built.bt)
    returns = np.asarray(final_returns(task, {"bt": bt_digest(built.bt)}, policy.act,
                                       episodes, cfg))
    size = tree.size()
    row = {"task": task.name, "agent": algo, "learner": LEARNER, "leaves_limit": leaves,
           "seed": seed, "rules": built.rules, "bt_nodes": built.bt.node_count,
           "tests": size["tests"], "test_terms": size["test_terms"],
           "command_terms": size["command_terms"],
           "max_features_read": _max_features(tree),
           "mean_return": float(returns.mean()), "std_return": float(returns.std()),
           "episodes": len(returns), "share_at_200": float((returns >= 200).mean()),
           "distilled_selection_mean": record["selection_means"][0],
           "refined_selection_mean": record["selection_means"][record["best_index"]],
           "digits": next((s["digits"] for s in record["stages"] if s["stage"] == "round"),
                          None),
           "refine_episodes": record["episodes"], "states_checked": built.states_checked,
           "disagreements": built.disagreements}
    return row, built


def _max_features(tree: ControllerArrays) -> int:
    """The most features any one test or command of the tree reads."""
    tests = (tree.split != 0).sum(axis=1)
    commands = (tree.weights != 0).sum(axis=2)
    return int(max(tests.max(initial=0), commands.max(initial=0)))


def reference_rows(task: Task, episodes: int, cfg: Config) -> list[dict[str, Any]]:
    """The reference controllers of ``task`` on the same final episodes."""
    from ibt.runs.reference_controllers import references

    rows = []
    for ref in references(task.name):
        returns = np.asarray(final_returns(task, {"reference": ref.name}, ref.act, episodes,
                                           cfg))
        rows.append({"task": task.name, "agent": "", "learner": ref.name, "leaves_limit": None,
                     "seed": None, "rules": ref.rules, "bt_nodes": None, "tests": None,
                     "test_terms": None, "command_terms": ref.terms,
                     "constants": ref.constants, "mean_return": float(returns.mean()),
                     "std_return": float(returns.std()), "episodes": len(returns),
                     "share_at_200": float((returns >= 200).mean()), "source": ref.source})
    return rows


def controllers_table(cfg: Config, experts: dict[str, str], episodes: int) -> Any:
    """Every run of the study (each task's leaf limits and seeds, :func:`budget_of`) and the
    task's reference controllers, on the same ``episodes`` final episodes: one row each."""
    import pandas as pd

    from ibt.tasks.catalogue import get_task

    rows: list[dict[str, Any]] = []
    for name, algo in experts.items():
        task = get_task(name)
        budget = budget_of(task, cfg)
        for leaves in budget.leaves:
            for seed in budget.seeds:
                row, built = controller_row(task, algo, leaves, seed, cfg, episodes)
                rows.append({**row, "rules_text": "\n".join(_rules(built.bt))})
        rows.extend(reference_rows(task, episodes, cfg))
    return pd.DataFrame(rows)


def _rules(bt: Any) -> list[str]:
    from ibt.synth.controller import rules_text

    return rules_text(bt)


def summary(table: Any) -> Any:
    """Per task and leaf limit: the mean over seeds and the best seed (chosen on these same
    episodes, so its number is flattered), beside each reference controller."""
    import pandas as pd

    ours = table[table.learner == LEARNER]
    grouped = ours.groupby(["task", "leaves_limit"]).agg(
        seeds=("seed", "count"), rules=("rules", "max"), bt_nodes=("bt_nodes", "max"),
        mean_of_seeds=("mean_return", "mean"), lowest_seed=("mean_return", "min"),
        best_seed=("mean_return", "max")).reset_index()
    grouped.insert(2, "what", "controller BT (ours)")
    refs = table[table.learner != LEARNER].rename(columns={"learner": "what"})
    refs = refs.assign(mean_of_seeds=refs.mean_return, best_seed=refs.mean_return,
                       lowest_seed=refs.mean_return, seeds=1)
    columns = ["task", "what", "leaves_limit", "seeds", "rules", "bt_nodes", "mean_of_seeds",
               "lowest_seed", "best_seed"]
    return pd.concat([grouped[columns], refs[columns]], ignore_index=True)


def best_runs(table: Any) -> Any:
    """Per task, the run with the highest mean return (ties: fewer BT nodes)."""
    ours = table[table.learner == LEARNER]
    return (ours.sort_values(["task", "mean_return", "bt_nodes"], ascending=[True, False, True])
            .groupby("task").head(1).reset_index(drop=True))


def controller_bt(cfg: Config, task: Task, algo: str, leaves: int, seed: int) -> Any:
    """The verified BT of one run (read from the cache)."""
    return verified(task, algo, leaves, seed, cfg)[2].bt
