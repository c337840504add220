"""Every stage's settings for one task under one profile: the budgets, in one home.

A budget is in deterministic units (episodes, labels, generations), never seconds, so a cached
result does not depend on the machine. Each builder starts from the task's catalogue entry
(``Task.budget``, ``Task.refine``, ``Task.evolve``) and shrinks it to seconds under the
``smoke`` profile. The builders follow different rules on purpose (a label floor for the
imitation loop, more CMA-ES generations for more episodes, a floor of one generation for a
search), so they stay separate functions; what they share, the ``smoke`` refinement, is
:data:`SMOKE_REFINE`.

The paper's grid, the front, both searches, the continuous study and ``pipeline`` read their
settings here, so a study and the pipeline that run the same stage on the same agent share its
cache entries.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from ibt.profiles import Config
from ibt.tasks.settings import EvolveConfig, RefineConfig
from ibt.tasks.task import Task

RELATIONAL = "imitation-bt+rel"  #: the relational learner's distillation method
COMMAND_TOLERANCE = 0.01  #: choose_commands' tolerance (share of expert minus random return)
BOX_SELECTION_EPISODES = 20  #: held-out episodes choosing the distillation's tree and its k

#: a refinement's settings under the ``smoke`` profile (seconds, not minutes): the task's
#: refinement and the structure search's polish
SMOKE_REFINE: dict[str, Any] = {"cma_generations": 2, "cma_episodes": 2, "cma_popsize": 4,
                                "sweep_episodes": 2, "sweep_rounds": 1, "selection_episodes": 3,
                                "n_envs": 8}


# --- distil -----------------------------------------------------------------------------------


def distill_config(cfg: Config, task: Task, method: str = "imitation-bt", **overrides: Any
                   ) -> Any:
    """The task's distillation settings (its catalogue entry's ``budget``) scaled to the
    profile's budgets, with ``overrides`` (e.g. ``max_leaf_nodes``)."""
    from ibt.distill.loop import DistillConfig

    budget = task.budget
    labels = max(50, round(budget.labels_per_iteration * cfg.labels_scale))
    iterations = min(cfg.n_iterations, budget.max_iterations or cfg.n_iterations)
    settings = {"n_iterations": iterations, "labels_per_iteration": labels,
                "selection_episodes": cfg.selection_episodes * budget.selection_scale, **overrides}
    return DistillConfig.for_task(task, method=method, **settings)


def box_config(cfg: Config, task: Task, method: str, leaves: int | None) -> Any:
    """The task's continuous distillation budget at a leaf limit, shrunk under ``smoke``."""
    from ibt.distill.continuous import BoxDistillConfig

    overrides: dict[str, Any] = {"method": method,
                                 "selection_episodes": min(BOX_SELECTION_EPISODES,
                                                           cfg.selection_episodes)}
    if leaves is not None:
        overrides["max_leaf_nodes"] = leaves
    if cfg.profile == "smoke":
        overrides.update(n_iterations=2, labels_per_iteration=300, eval_envs=3)
    return BoxDistillConfig.for_task(task, **overrides)


def learner_params() -> dict[str, Any]:
    """The relational learner's settings, part of every ``distill-rel`` key."""
    from ibt.distill.relational import RelationalSettings

    return RelationalSettings().as_params()


# --- refine -----------------------------------------------------------------------------------


def refine_config(cfg: Config, task: Task, **overrides: Any) -> RefineConfig:
    """The task's refinement budget (:func:`ibt.refine.by_return.task_config`), shrunk to
    seconds under the ``smoke`` profile."""
    from ibt.refine.by_return import task_config

    config = task_config(task, **overrides)
    if cfg.profile == "smoke":
        config = replace(config, episodes=min(config.episodes, 240), **SMOKE_REFINE)
    return config


def cma_only(config: RefineConfig) -> RefineConfig:
    """``config`` with its CMA-ES stages only: a command tree's values are tuned with its
    thresholds, and its leaves are not pruned."""
    return replace(config, stages=tuple(s for s in config.stages if s == "cma") or ("cma",))


def box_refine_config(cfg: Config, task: Task) -> RefineConfig:
    """The task's refinement budget for a command tree, shrunk under ``smoke``."""
    return cma_only(refine_config(cfg, task))


def box_refine_task_config(task: Task, **overrides: Any) -> RefineConfig:
    """The task's refinement budget with ``overrides``, its CMA-ES stages only (a user's task
    without a budget of its own gets the default's)."""
    return cma_only(replace(task.refine, **overrides))


def scaled_refine_config(cfg: Config, task: Task, scale: float, episodes: int | None,
                         commands: bool = False) -> RefineConfig:
    """The task's refinement budget scaled by ``scale`` (or ``episodes`` per tree), with CMA-ES
    generations grown in proportion; CMA-ES stages only for a command tree."""
    config = box_refine_config(cfg, task) if commands else refine_config(cfg, task)
    total = episodes or max(10, round(config.episodes * scale))
    generations = max(config.cma_generations,
                      math.ceil(config.cma_generations * total / config.episodes))
    return replace(config, episodes=total, cma_generations=generations)


# --- structure search -------------------------------------------------------------------------


def evolve_config(cfg: Config, task: Task, max_leaves: int, use_expert: bool = True
                  ) -> EvolveConfig:
    """The task's structure-search budget at a leaf limit, shrunk to seconds under ``smoke``;
    ``use_expert=False`` is the ablation without the expert's labels (reward alone)."""
    config = replace(task.evolve or EvolveConfig(), max_leaves=max_leaves)
    if not use_expert:
        config = replace(config, use_expert=False)
    if cfg.profile == "smoke":
        config = replace(config, episodes=240, mu=2, lam=4, generation_episodes=2,
                         pool_episodes=2, selection_episodes=3, finalists=3, n_envs=8,
                         refine_episodes=60)
    return config


def relational_search_config(cfg: Config, task: Task, max_leaves: int,
                             search_episodes: int | None = None, leaf_rule: str = "vote"
                             ) -> EvolveConfig:
    """Imitation-BT+SR's search settings at ``max_leaves`` (Imitation-BT+S's,
    :func:`evolve_config`), with the search's episode budget ``search_episodes`` where given
    (the task's budget otherwise, and always under ``smoke``) and the expert's ``leaf_rule``
    (:attr:`ibt.tasks.settings.EvolveConfig.leaf_rule`)."""
    config = replace(evolve_config(cfg, task, max_leaves), leaf_rule=leaf_rule)
    if search_episodes is not None and cfg.profile != "smoke":
        if search_episodes < config.generation_episodes:
            raise ValueError(f"a search budget of {search_episodes} episodes is below one "
                             f"generation ({config.generation_episodes}); give more")
        config = replace(config, episodes=int(search_episodes))
    return config


def search_config(cfg: Config, task: Task, leaves: int, scale: float) -> EvolveConfig:
    """The task's structure-search budget at ``leaves``, its episodes scaled by ``scale`` (not
    under ``smoke``), never below one generation and its pool."""
    config = evolve_config(cfg, task, leaves)
    if cfg.profile != "smoke" and scale != 1.0:
        per_generation = (config.mu + config.lam) * config.generation_episodes
        config = replace(config, episodes=max(round(config.episodes * scale),
                                              per_generation + config.pool_episodes))
    return config


def polish_config(cfg: Config, config: EvolveConfig) -> RefineConfig:
    """CMA-ES on the thresholds, then free pruning, under the same leaf limit."""
    polish = RefineConfig(stages=("cma", "prune"), episodes=config.refine_episodes,
                          cma_generations=400, cma_episodes=16, max_leaves=config.max_leaves,
                          selection_episodes=config.selection_episodes)
    if cfg.profile == "smoke":
        polish = replace(polish, **SMOKE_REFINE)
    return polish


#: a polish again (:mod:`ibt.engine.polish`) runs this many times the search's polish episodes
AGAIN_FACTOR = 2


def again_config(cfg: Config, task: Task, leaves: int, scale: float) -> RefineConfig:
    """The search's polish at ``leaves``, with :data:`AGAIN_FACTOR` times its episodes: a
    polish again."""
    polish = polish_config(cfg, search_config(cfg, task, leaves, scale))
    return replace(polish, episodes=AGAIN_FACTOR * polish.episodes)
