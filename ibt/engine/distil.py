"""The distillation stage: the interactive loop at a leaf limit with one of the learners.

``axis`` (CART), ``relational`` (splits on ``w1 * x_i + w2 * x_j``) or ``box`` (a regression
tree whose leaves are then merged into named commands, :mod:`ibt.engine.commands`). Keys are
the grid's and the front's, with the agent's digest (``expert_sha256``: a checkpoint's bytes,
or a callable's module and name); budgets are in episodes, never seconds, so a cached result
does not depend on the machine.
"""

from __future__ import annotations

from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine import budgets
from ibt.engine.agent import Agent
from ibt.profiles import Config

LEARNERS = ("axis", "relational", "box")


def import_env_modules(modules: tuple[str, ...]) -> None:
    """The user's environment modules, imported first in a worker process that runs a stage
    (their tasks register on import)."""
    from ibt.tasks.catalogue import import_env_module

    for module in modules:
        import_env_module(module)


def distill_key(cfg: Config, agent: Agent, seed: int, learner: str = "axis",
                method: str | None = None, **overrides: Any) -> tuple[str, dict, Any]:
    """The cache kind, key parameters and settings of one distillation (``overrides`` of the
    task's budget, e.g. ``max_leaf_nodes``; a Box task takes only that one): the one place
    where the ``distill``, ``distill-rel`` and ``box-distill`` keys are written."""
    task = agent.task
    if learner == "box":
        leaves = overrides.pop("max_leaf_nodes", None)
        if overrides:
            raise TypeError(f"a Box distillation takes max_leaf_nodes only, not "
                            f"{sorted(overrides)}")
        config = budgets.box_config(cfg, task, method or box_method(agent), leaves)
        kind = "box-distill"
        extra: dict[str, Any] = {}
    else:
        relational = learner == "relational"
        method = budgets.RELATIONAL if relational else method or "imitation-bt"
        config = budgets.distill_config(cfg, task, method, **overrides)
        kind = "distill-rel" if relational else "distill"
        extra = {"learner": budgets.learner_params()} if relational else {}
    params = {"task": task.key, "algo": agent.algo, "seed": seed, "config": config.as_params(),
              **extra, "expert_sha256": agent.digest}
    return kind, params, config


def distillation(cfg: Config, agent: Agent, seed: int, learner: str = "axis",
                 method: str | None = None, **overrides: Any) -> Any:
    """One distillation run (cached): a :class:`ibt.distill.loop.Distillation` (``axis``,
    ``relational``), or for ``box`` a plain document (``iterations``, ``best_index``, ``tree``
    as :func:`ibt.distill.continuous.regressor_doc`, ``wall_seconds``)."""
    kind, params, config = distill_key(cfg, agent, seed, learner, method, **overrides)
    if learner == "box":
        from ibt.distill.continuous import distill_box, regressor_doc

        def fit() -> dict[str, Any]:
            run = distill_box(agent.task, agent.load(), config, seed, progress=cfg.progress)
            return {"iterations": run.iterations, "best_index": run.best_index,
                    "tree": regressor_doc(run.best_tree), "wall_seconds": run.wall_seconds}

        return load_or_compute(kind, params, fit, cache_dir=cfg.cache_dir, codec="json",
                               refresh=cfg.refresh)
    from ibt.distill.loop import distill

    def compute() -> Any:
        return distill(agent.task, agent.load(), config, seed, progress=cfg.progress)

    return load_or_compute(kind, params, compute, cache_dir=cfg.cache_dir,
                           codec="distillation", refresh=cfg.refresh)


def distil(cfg: Config, agent: Agent, leaves: int, seed: int, learner: str,
           env_modules: tuple[str, ...] = ()) -> Any:
    """The distilled tree at ``leaves``: a classifier (``axis``, ``relational``) or, on a Box
    task, command arrays (``box``: regression tree, then its leaves merged into commands).
    Runs in a worker process too (the user's environment modules are imported there first)."""
    import_env_modules(env_modules)
    run = distillation(cfg, agent, seed, learner, max_leaf_nodes=leaves)
    if learner == "box":
        from ibt.engine.commands import commands
        from ibt.refine.commands import CommandArrays

        return CommandArrays.from_doc(commands(cfg, agent, run["tree"], seed)["arrays"])
    return run.best_tree


def box_method(agent: Agent) -> str:
    """Critic-weighted imitation for SAC and TD3 agents (their critic scores any action);
    plain DAgger for the others."""
    return "imitation-bt" if agent.algo in ("sac", "td3") else "dagger"
