"""The distillation stage: the interactive loop at a leaf limit with one of the registered
learners (:mod:`ibt.engine.learners`: ``axis``, ``relational``, ``box``, ...).

Keys are the grid's and the front's, with the agent's digest (``expert_sha256``: a
checkpoint's bytes, or a callable's module and name); budgets are in episodes, never seconds,
so a cached result does not depend on the machine.
"""

from __future__ import annotations

from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine.agent import Agent
from ibt.engine.learners import get_learner
from ibt.profiles import Config


def import_env_modules(modules: tuple[str, ...]) -> None:
    """The user's environment modules, imported first in a worker process that runs a stage
    (their tasks, and any learner they register, register on import)."""
    from ibt.tasks.catalogue import import_env_module

    for module in modules:
        import_env_module(module)


def distill_key(cfg: Config, agent: Agent, seed: int, learner: str = "axis",
                method: str | None = None, **overrides: Any) -> tuple[str, dict, Any]:
    """The cache kind, key parameters and settings of one distillation (``overrides`` of the
    task's budget, e.g. ``max_leaf_nodes``): the one place where every learner's distillation
    key (``distill``, ``distill-rel``, ``box-distill``, ...) is written."""
    entry = get_learner(learner)
    config = entry.settings(cfg, agent, method, overrides)
    params = {"task": agent.task.key, "algo": agent.algo, "seed": seed,
              "config": config.as_params(), **entry.params(),
              "expert_sha256": agent.digest}  # as distillation_of keys it
    return entry.kind, params, config


def distillation(cfg: Config, agent: Agent, seed: int, learner: str = "axis",
                 method: str | None = None, **overrides: Any) -> Any:
    """One distillation run (cached under the learner's kind and codec): a
    :class:`ibt.distill.loop.Distillation` (``axis``, ``relational``), or for ``box`` a plain
    document (``iterations``, ``best_index``, ``tree`` as
    :func:`ibt.distill.continuous.regressor_doc`, ``wall_seconds``)."""
    _, _, config = distill_key(cfg, agent, seed, learner, method, **overrides)
    return distillation_of(cfg, agent, seed, learner, config)


def distillation_of(cfg: Config, agent: Agent, seed: int, learner: str, config: Any) -> Any:
    """One distillation run with explicit settings (a study's own budget), keyed as
    :func:`distill_key` keys it."""
    entry = get_learner(learner)
    params = {"task": agent.task.key, "algo": agent.algo, "seed": seed,
              "config": config.as_params(), **entry.params(),
              "expert_sha256": agent.digest}
    return load_or_compute(entry.kind, params, lambda: entry.fit(cfg, agent, config, seed),
                           cache_dir=cfg.cache_dir, codec=entry.codec, refresh=cfg.refresh)


def distil(cfg: Config, agent: Agent, leaves: int, seed: int, learner: str,
           env_modules: tuple[str, ...] = ()) -> Any:
    """The learner's distilled tree at ``leaves``: a classifier (``axis``, ``relational``) or,
    on a Box task, command arrays (``box``: regression tree, then its leaves merged into
    commands). Runs in a worker process too (the user's environment modules are imported
    there first)."""
    import_env_modules(env_modules)
    run = distillation(cfg, agent, seed, learner, max_leaf_nodes=leaves)
    return get_learner(learner).tree(cfg, agent, run, seed)
