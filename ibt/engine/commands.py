"""The commands stage of a Box task: a regression tree's leaves merged into the fewest named
commands that keep its held-out return (kind ``box-commands``)."""

from __future__ import annotations

from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine import budgets
from ibt.engine.agent import Agent
from ibt.engine.keys import doc_digest
from ibt.engine.measure import rolled
from ibt.evaluate.rollouts import selection_seeds
from ibt.profiles import Config


def commands(cfg: Config, agent: Agent, tree_doc: dict[str, Any], seed: int) -> dict[str, Any]:
    """A regression tree's leaves merged into the fewest named commands that keep its held-out
    return within a tolerance (kind ``box-commands``): ``arrays`` (a ``CommandArrays``
    document), ``rows`` (every count tried), ``scale`` (agent minus random return there)."""
    from ibt.distill.continuous import regressor_from_doc
    from ibt.refine.commands import CommandArrays
    from ibt.synth.commands import DECIMALS, choose_commands

    task = agent.task
    n = min(budgets.BOX_SELECTION_EPISODES, cfg.selection_episodes)
    params = {"task": task.key, "algo": agent.algo, "seed": seed, "tree": doc_digest(tree_doc),
              "episodes": n, "tolerance": budgets.COMMAND_TOLERANCE, "decimals": DECIMALS}

    def choose() -> dict[str, Any]:
        seeds = selection_seeds(n, seed, offset=1)
        scale = (rolled(task, lambda: agent.load().act, seeds).mean
                 - rolled(task, lambda: agent.random_act(seed), seeds).mean)
        chosen, rows = choose_commands(regressor_from_doc(tree_doc), task, seeds,
                                       scale=scale, tolerance=budgets.COMMAND_TOLERANCE, seed=seed)
        return {"arrays": CommandArrays.from_command_tree(chosen).to_doc(), "rows": rows,
                "scale": scale}

    return load_or_compute("box-commands", params, choose, cache_dir=cfg.cache_dir,
                           codec="json", refresh=cfg.refresh)
