"""The refinement stage: a tree refined by return (thresholds, leaves, pruning; a command
tree's values too), cached under ``refine``, ``refine-rel`` or ``box-refine``: the cached
refinements the learners' entries (:mod:`ibt.engine.learners`) and the studies call."""

from __future__ import annotations

from typing import Any

from ibt.cache.store import load_or_compute, tree_digest
from ibt.engine.agent import Agent
from ibt.engine.distil import import_env_modules
from ibt.engine.keys import doc_digest
from ibt.profiles import Config
from ibt.tasks.task import Task


def command_refinement(cfg: Config, agent: Agent, arrays: Any, seed: int, config: Any) -> Any:
    """A command tree refined by return, thresholds and commands' values (kind
    ``box-refine``): the :class:`ibt.refine.commands.CommandRefinement` record."""
    from ibt.refine.commands import CommandRefinement, refine_commands
    from ibt.synth.commands import DECIMALS

    task = agent.task
    params = {"task": task.key, "algo": agent.algo, "seed": seed,
              "tree": doc_digest(arrays.to_doc()), "config": config.as_params(),
              "decimals": DECIMALS}

    def compute() -> dict[str, Any]:
        return refine_commands(arrays, task, config, seed, decimals=DECIMALS,
                               progress=cfg.progress).to_doc()

    doc = load_or_compute("box-refine", params, compute, cache_dir=cfg.cache_dir, codec="json",
                          refresh=cfg.refresh)
    return CommandRefinement.from_doc(doc)


def refinement_cached(cfg: Config, task: Task, algo: str, seed: int, source_method: str,
                      tree: Any, config: Any) -> Any:
    """``tree`` refined by return (:func:`ibt.refine.by_return.refine`, or
    :func:`ibt.refine.relational.refine_relational` for a relational tree), cached under
    ``refine`` or ``refine-rel`` on the method it came from, the tree and the settings: the
    one home of a cached refinement (Imitation-BT+, the searches' polish, the pipeline)."""
    from ibt.distill.relational import RelationalTreeClassifier
    from ibt.refine.by_return import refine as refine_by_return
    from ibt.refine.relational import refine_relational

    relational = isinstance(tree, RelationalTreeClassifier)
    params = {"task": task.name, "algo": algo, "seed": seed, "source_method": source_method,
              "tree": tree_digest(tree), "config": config.as_params()}

    def compute() -> Any:
        if relational:
            return refine_relational(tree, task, config, seed, progress=cfg.progress)
        return refine_by_return(tree, task, config, seed, progress=cfg.progress)

    return load_or_compute("refine-rel" if relational else "refine", params, compute,
                           cache_dir=cfg.cache_dir, codec="refinement", refresh=cfg.refresh)


def refine(cfg: Config, agent: Agent, learner: str, tree: Any, seed: int, scale: float = 1.0,
           episodes: int | None = None, env_modules: tuple[str, ...] = ()) -> Any:
    """``tree``, the ``learner``'s, refined by return as its registry entry says (kinds
    ``refine``, ``refine-rel``, ``box-refine``, ...): the refinement's chosen tree. Runs in a
    worker process too (the user's environment modules are imported there first)."""
    from ibt.engine.learners import get_learner

    import_env_modules(env_modules)
    return get_learner(learner).refine(cfg, agent, tree, seed, scale, episodes)
