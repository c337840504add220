"""The ``oblique`` and ``controller`` learners: every stage of the engine for their trees.

``oblique`` (discrete actions) grows trees whose tests read up to four features,
``w1 * x1 + ... + wk * xk > t`` (:mod:`ibt.distill.oblique`); ``controller`` (``Box`` actions)
grows such tests with commands linear in up to four features (:mod:`ibt.distill.controller`).
Both are distilled in the interactive loop (cache kind ``controller-distil``), refined by return
with CMA-ES over thresholds, test weights and commands, constants rounded to the fewest digits
that keep the return (:mod:`ibt.refine.controller`, kind ``controller-refine``), and laid out as
one verified BT of one rule per leaf (:mod:`ibt.synth.controller`), rolled out as that BT.

This module is the model of a learner added to the engine: its settings, loop, cached
refinement and BT layout beside its :class:`ibt.engine.learners.Learner` entries
(:data:`LEARNERS`), registered when it is imported (:data:`ibt.engine.learners.BUILT_IN`
imports it).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ibt.cache.store import load_or_compute
from ibt.engine import budgets
from ibt.engine.agent import Agent
from ibt.engine.learners import BOX, DISCRETE, Learner, register_learner
from ibt.profiles import Config
from ibt.tasks.task import Task

MAX_ITERATIONS = 10  #: the loop's iterations at most (its best tree came by 8 in the study)


def controller_config(cfg: Config, task: Task, leaves: int | None) -> Any:
    """A controller tree's (``Box`` task) or oblique tree's (discrete task) distillation at a
    leaf limit: the task's labels per iteration, at most :data:`MAX_ITERATIONS` iterations,
    shrunk under ``smoke``."""
    from ibt.distill.controller import ControllerConfig
    from ibt.distill.oblique import ObliqueConfig

    kind = ControllerConfig if task.continuous else ObliqueConfig
    overrides: dict[str, Any] = {
        "n_iterations": min(MAX_ITERATIONS, task.budget.max_iterations or cfg.n_iterations),
        "labels_per_iteration": task.budget.labels_per_iteration,
        "selection_episodes": min(budgets.BOX_SELECTION_EPISODES, cfg.selection_episodes)}
    if leaves is not None:
        overrides["max_leaves"] = leaves
    if cfg.profile == "smoke":
        overrides.update(n_iterations=2, labels_per_iteration=300, eval_envs=3)
    return kind(**overrides)


def controller_refinement(cfg: Config, task: Task, tree: Any, seed: int, config: Any,
                          tolerance: float) -> dict[str, Any]:
    """A controller or oblique tree refined by return (kind ``controller-refine``): the record
    of :func:`ibt.refine.controller.refine_controller` as a document."""
    from ibt.refine.controller import refine_controller

    params = {"task": task.key, "source": tree.digest(), "seed": seed,
              "config": config.as_params(), "tolerance": tolerance}

    def compute() -> dict[str, Any]:
        return refine_controller(tree, task, config, seed, tolerance=tolerance,
                                 progress=cfg.progress).to_doc()

    return load_or_compute("controller-refine", params, compute, cache_dir=cfg.cache_dir,
                           refresh=cfg.refresh)


def _settings(cfg: Config, agent: Agent, method: str | None, overrides: dict[str, Any]) -> Any:
    """The loop's settings at a leaf limit (its one override)."""
    overrides = dict(overrides)
    leaves = overrides.pop("max_leaf_nodes", None)
    if overrides:
        raise TypeError(f"a controller distillation takes max_leaf_nodes only, not "
                        f"{sorted(overrides)}")
    config = controller_config(cfg, agent.task, leaves)
    return replace(config, method=method) if method else config


def _fit(cfg: Config, agent: Agent, config: Any, seed: int) -> dict[str, Any]:
    """The loop with a model tree (Box) or an oblique tree (discrete): ``tree`` (its
    document), ``iterations``, ``best_index``, ``wall_seconds``."""
    from ibt.distill.controller import distill_controller
    from ibt.distill.oblique import distill_oblique

    learn = distill_controller if agent.continuous else distill_oblique
    run = learn(agent.task, agent.load(), config, seed, progress=cfg.progress)
    return {"tree": run.best_tree.to_doc(), "iterations": run.iterations,
            "best_index": run.best_index, "wall_seconds": run.wall_seconds}


def _tree(cfg: Config, agent: Agent, run: dict[str, Any], seed: int) -> Any:
    from ibt.refine.controller import tree_from_doc

    return tree_from_doc(run["tree"])


def _refine(cfg: Config, agent: Agent, tree: Any, seed: int, scale: float,
            episodes: int | None) -> Any:
    """Thresholds, test weights and commands refined by return, constants rounded to the
    fewest digits that keep the return (:func:`controller_refinement`)."""
    from ibt.refine.controller import tree_from_doc

    config = budgets.scaled_refine_config(cfg, agent.task, scale, episodes, commands=True)
    record = controller_refinement(cfg, agent.task, tree, seed, config, tolerance=0.0)
    return tree_from_doc(record["candidates"][record["best_index"]])


def _lay_out(agent: Agent, tree: Any, seed: int) -> dict[str, Any]:
    """The tree's one BT (one rule per leaf), checked on random and boundary states (not
    cached: it is laid out, not searched for)."""
    from ibt.synth.controller import SYNTHESISER, check_states, controller_bt

    states = check_states(tree, agent.task, np.zeros((0, agent.task.n_features)), seed=seed)
    return {SYNTHESISER: controller_bt(tree, agent.task, states).bt}


#: the two entries, registered in this order
LEARNERS = (
    Learner("oblique", DISCRETE, "controller-distil", "json", _settings, _fit, _tree, _refine,
            min_features=2, combines_features=True, lay_out=_lay_out,
            trees=("ibt.distill.oblique.ObliqueArrays",), measured_as_bt=True,
            description="tests of up to four features, w1 * x1 + ... + wk * xk > t"),
    Learner("controller", BOX, "controller-distil", "json", _settings, _fit, _tree, _refine,
            combines_features=True, lay_out=_lay_out,
            trees=("ibt.distill.controller.ControllerArrays",), measured_as_bt=True,
            description="tests of up to four features and commands linear in up to four"),
)
for _entry in LEARNERS:
    register_learner(_entry)
