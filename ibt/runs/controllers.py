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

from ibt.distill.controller import ControllerArrays, ControllerConfig
from ibt.distill.oblique import ObliqueArrays, ObliqueConfig
from ibt.evaluate.rollouts import final_seeds, visited_features
from ibt.profiles import Config
from ibt.tasks.settings import RefineConfig
from ibt.tasks.task import Task

LEARNER = "controller"  #: linear commands (Box tasks)
OBLIQUE = "oblique"  #: tests of up to four features (discrete tasks)
OURS = (LEARNER, OBLIQUE)


@dataclass(frozen=True)
class ControllerBudget:
    """One task's controller settings: the loop's, refinement's and the study's grid."""

    distil: ControllerConfig | ObliqueConfig
    refine: RefineConfig
    leaves: tuple[int, ...]
    seeds: tuple[int, ...] = (0, 1, 2)
    tolerance: float = 0.5  # return (task units) rounding the constants may cost


#: per task: chosen before the study's results, from the tasks' episode lengths and one
#: refinement trial each on this machine (MountainCarContinuous, 2 leaves: 93.3 -> 97.8 on the
#: held-out episodes in 3,000 episodes; Pendulum, 3 leaves: -448 -> -170 in 6,000, whose noisy
#: generations of 8 episodes led to 16 here). The LunarLander grids were planned at 3 and 4
#: (discrete) and 4 and 8 leaves (continuous) and cut to 4 leaves when the first runs showed
#: one run took 15-25 minutes of a loaded machine: every seed of one limit before more limits
#: MountainCarContinuous and Pendulum then went from 16 to 64 episodes a candidate (and 100 to
#: 400 held-out episodes), after seeing their results: MountainCarContinuous's BTs failed on
#: 1-2 % of start positions (a closed-loop rest point near -0.52 that 16 episodes rarely
#: visit), and Pendulum's returns (std 90 an episode) made 16-episode generations guesswork.
#: Both tasks run 30-100 thousand steps a second, so four times the episodes is minutes
BUDGETS: dict[str, ControllerBudget] = {
    "MountainCarContinuous-v0": ControllerBudget(
        ControllerConfig(max_leaves=2, n_iterations=8, labels_per_iteration=3000),
        RefineConfig(stages=("cma", "cma"), episodes=40_000, cma_generations=40,
                     cma_episodes=64, selection_episodes=400), leaves=(1, 2), tolerance=0.2),
    "Pendulum-v1": ControllerBudget(
        ControllerConfig(max_leaves=4, n_iterations=8, labels_per_iteration=3000),
        RefineConfig(stages=("cma", "cma"), episodes=48_000, cma_generations=40,
                     cma_episodes=64, selection_episodes=400), leaves=(2, 3, 4), tolerance=2.0),
    "LunarLander-v3": ControllerBudget(
        ObliqueConfig(max_leaves=4, n_iterations=10, labels_per_iteration=4000),
        RefineConfig(stages=("cma", "cma"), episodes=12_000, cma_generations=60,
                     cma_episodes=8, selection_episodes=100), leaves=(4,), tolerance=2.0),
    "LunarLanderContinuous-v3": ControllerBudget(
        ControllerConfig(max_leaves=8, n_iterations=10, labels_per_iteration=4000),
        RefineConfig(stages=("cma", "cma"), episodes=12_000, cma_generations=60,
                     cma_episodes=8, selection_episodes=100), leaves=(4,), tolerance=2.0),
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


def distilled(task: Task, algo: str, leaves: int, seed: int, cfg: Config
              ) -> ControllerArrays | ObliqueArrays:
    """The controller tree (``Box`` task) or oblique tree (discrete task) distilled from the
    committed agent under the study's budget (the engine's distillation stage, cached)."""
    from ibt.engine.distil import distillation_of
    from ibt.refine.controller import tree_from_doc

    config = replace(budget_of(task, cfg).distil, max_leaves=leaves)
    run = distillation_of(cfg, _agent(task, algo, cfg), seed, learner_of(task), config)
    return tree_from_doc(run["tree"])


def learner_of(task: Task) -> str:
    """The study's learner on ``task``: controller trees for a Box, oblique trees else."""
    return LEARNER if task.continuous else OBLIQUE


def refined(task: Task, algo: str, leaves: int, seed: int, cfg: Config) -> dict[str, Any]:
    """The refinement record of the distilled tree (the engine's controller refinement,
    cached): candidates, stages, choice."""
    from ibt.engine.controller_learners import controller_refinement

    budget = budget_of(task, cfg)
    return controller_refinement(cfg, task, distilled(task, algo, leaves, seed, cfg), seed,
                                 budget.refine, budget.tolerance)


def final_returns(task: Task, what: dict[str, Any], act: Any, episodes: int, cfg: Config
                  ) -> list[float]:
    """A policy's returns on the first ``episodes`` final episodes (the engine's measurement,
    kind ``returns``)."""
    from ibt.engine.measure import returns_of

    return returns_of(cfg, task, what, lambda: act, final_seeds(episodes)).returns


def verified(task: Task, algo: str, leaves: int, seed: int, cfg: Config
             ) -> tuple[dict[str, Any], ControllerArrays | ObliqueArrays, Any]:
    """One run's refinement record, its chosen tree and that tree's verified BT
    (:class:`ibt.synth.controller.ControllerBT`, checked on the states of 4 final episodes,
    random states and both sides of every axis test)."""
    from ibt.refine.controller import ControllerPopulation, tree_from_doc
    from ibt.synth.controller import check_states, controller_bt

    record = refined(task, algo, leaves, seed, cfg)
    tree = tree_from_doc(record["candidates"][record["best_index"]])
    population = ControllerPopulation.of([tree], task)
    visited = visited_features(  # states to check the BT on
        task, lambda x: population.decide(x, np.zeros(len(x), np.int64)), final_seeds(4),
        n_envs=4)
    built = controller_bt(tree, task, check_states(tree, task, visited,
                                                   seed=seed))
    return record, tree, built


def controller_row(task: Task, algo: str, leaves: int, seed: int, cfg: Config,
                   episodes: int) -> tuple[dict[str, Any], Any]:
    """One refined controller's row and its verified BT, measured on ``episodes`` final
    episodes."""
    from ibt.engine.keys import bt_digest
    from ibt.evaluate.policies import BTPolicy
    from ibt.synth.commands import CommandBTPolicy

    record, tree, built = verified(task, algo, leaves, seed, cfg)
    act = (CommandBTPolicy(task, built.bt).act if task.continuous
           else BTPolicy(task, built.bt).act)
    returns = np.asarray(final_returns(task, {"bt": bt_digest(built.bt)}, act, episodes, cfg))
    size = tree.size()
    learner = learner_of(task)
    row = {"task": task.name, "agent": algo, "learner": learner, "leaves_limit": leaves,
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


def _max_features(tree: ControllerArrays | ObliqueArrays) -> int:
    """The most features any one test or command of the tree reads."""
    tests = (tree.split != 0).sum(axis=1)
    commands = ((tree.weights != 0).sum(axis=2) if isinstance(tree, ControllerArrays)
                else np.zeros(1, dtype=np.int64))
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
    return pd.DataFrame(rows).reindex(columns=COLUMNS)


COLUMNS = ["task", "agent", "learner", "leaves_limit", "seed", "rules", "bt_nodes", "tests",
           "test_terms", "command_terms", "constants", "max_features_read", "mean_return",
           "std_return", "episodes", "share_at_200", "distilled_selection_mean",
           "refined_selection_mean", "digits", "refine_episodes", "states_checked",
           "disagreements", "source", "rules_text"]


def _rules(bt: Any) -> list[str]:
    from ibt.synth.controller import rules_text

    return rules_text(bt)


def summary(table: Any) -> Any:
    """Per task and leaf limit: the mean over seeds and the best seed (chosen on these same
    episodes, so its number is flattered), beside each reference controller."""
    import pandas as pd

    ours = table[table.learner.isin(OURS)]
    grouped = ours.groupby(["task", "leaves_limit"]).agg(
        seeds=("seed", "count"), rules=("rules", "max"), bt_nodes=("bt_nodes", "max"),
        mean_of_seeds=("mean_return", "mean"), lowest_seed=("mean_return", "min"),
        best_seed=("mean_return", "max")).reset_index()
    grouped.insert(2, "what", "our BT")
    refs = table[~table.learner.isin(OURS)].rename(columns={"learner": "what"})
    refs = refs.assign(mean_of_seeds=refs.mean_return, best_seed=refs.mean_return,
                       lowest_seed=refs.mean_return, seeds=1)
    columns = ["task", "what", "leaves_limit", "seeds", "rules", "bt_nodes", "mean_of_seeds",
               "lowest_seed", "best_seed"]
    return pd.concat([grouped[columns], refs[columns]], ignore_index=True)


def best_runs(table: Any) -> Any:
    """Per task, the run with the highest mean return (ties: fewer BT nodes)."""
    ours = table[table.learner.isin(OURS)]
    return (ours.sort_values(["task", "mean_return", "bt_nodes"], ascending=[True, False, True])
            .groupby("task").head(1).reset_index(drop=True))


def controller_bt(cfg: Config, task: Task, algo: str, leaves: int, seed: int) -> Any:
    """The verified BT of one run (read from the cache)."""
    return verified(task, algo, leaves, seed, cfg)[2].bt


@dataclass(frozen=True)
class Target:
    """A bar set before the study's results: at least ``mean_return`` over the final episodes
    with at most ``rules`` rules and ``bt_nodes`` nodes, beside the named reference."""

    mean_return: float
    rules: int
    bt_nodes: int
    reference: str


#: the bars, each a hand-written or symbolic controller's return at a comparable size
TARGETS: dict[str, Target] = {
    "LunarLanderContinuous-v3": Target(283.3, 8, 40, "Gymnasium heuristic (283.3)"),
    "Pendulum-v1": Target(-155.0, 4, 16, "DSP formula (-163.3)"),
    "MountainCarContinuous-v0": Target(98.5, 2, 8, "DSP's comment, 99.09 (not runnable)"),
    "LunarLander-v3": Target(240.0, 4, 16, "Gymnasium heuristic (239.6)"),
}


def targets_table(table: Any) -> Any:
    """Per task with a bar: the best run within the bar's size and the best leaf limit's mean
    over seeds (both on the same final episodes), and whether each clears the bar."""
    import pandas as pd

    rows = []
    for task, target in TARGETS.items():
        ours = table[(table.task == task) & table.learner.isin(OURS)]
        if ours.empty:
            continue
        fits = ours[(ours.rules <= target.rules) & (ours.bt_nodes <= target.bt_nodes)]
        best = fits.sort_values(["mean_return", "bt_nodes"], ascending=[False, True]).head(1)
        by_limit = fits.groupby("leaves_limit").mean_return.agg(["mean", "min", "max", "count"])
        top = by_limit.sort_values("mean", ascending=False).head(1)
        rows.append({
            "task": task, "bar": target.mean_return, "max_rules": target.rules,
            "max_bt_nodes": target.bt_nodes, "reference": target.reference,
            "best_run": float(best.mean_return.iloc[0]) if len(best) else None,
            "best_run_rules": int(best.rules.iloc[0]) if len(best) else None,
            "best_run_bt_nodes": int(best.bt_nodes.iloc[0]) if len(best) else None,
            "best_run_seed": int(best.seed.iloc[0]) if len(best) else None,
            "best_limit": int(top.index[0]) if len(top) else None,
            "mean_of_seeds": float(top["mean"].iloc[0]) if len(top) else None,
            "seeds": int(top["count"].iloc[0]) if len(top) else 0,
            "lowest_seed": float(top["min"].iloc[0]) if len(top) else None,
            "best_run_clears": bool(len(best) and best.mean_return.iloc[0] >= target.mean_return),
            "mean_clears": bool(len(top) and top["mean"].iloc[0] >= target.mean_return)})
    return pd.DataFrame(rows)
