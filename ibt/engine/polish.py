"""Spare time's stage: a searched tree polished again.

A search polishes each of its best restarts once (CMA-ES on the thresholds, then free pruning).
On LunarLander (PPO, 8 leaves) polishing the chosen 20-node tree a second time moved its mean
over 1,000 fresh episodes from 236.3 to 236.1 and 239.2 (two seeds, the polish's episodes) and
to 245.2 and 238.3 (two seeds, twice them): the polish had not converged. So time the ladder
has left over goes to polishing again, each core one seed at
:data:`ibt.engine.budgets.AGAIN_FACTOR` times the polish's episodes (settings chosen after that
one experiment, :func:`ibt.engine.budgets.again_config`), the tree kept only where a polished
one beats it on the search's own choice episodes (never the recommendation's).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

from ibt.engine import budgets, search
from ibt.engine.agent import Agent
from ibt.engine.keys import leaves_of
from ibt.engine.learners import get_learner
from ibt.engine.parallel import parallel_map, processes, wall
from ibt.evaluate.rollouts import selection_seeds
from ibt.profiles import Config
from ibt.tasks.task import Task

if TYPE_CHECKING:
    from ibt.engine.ladder import Ladder, Settings
    from ibt.engine.plan import Replay

AGAIN_ROUNDS = 3  # at most this many rounds, each from the last one's tree


def polish_again(cfg: Config, agent: Agent, tree: Any, leaves: int, seed: int,
                 seeds: tuple[int, ...], *, relational: bool, scale: float = 1.0,
                 n_jobs: int = 1, env_modules: tuple[str, ...] = ()
                 ) -> tuple[Any | None, tuple[float, ...]]:
    """``tree`` (a search's winner at ``leaves``, run ``seed``) polished from each of ``seeds``
    (one a core): the best polished tree where it beats ``tree`` on the search's choice
    episodes, else None; and the choice means, ``tree``'s first. Each polish is cached."""
    config = budgets.search_config(cfg, agent.task, leaves, scale)
    choice = selection_seeds(search.choice_episodes(config), seed,
                             offset=search.RESTART_CHOICE_OFFSET)
    method = search.SEARCHED_REL if relational else search.SEARCHED
    polish = budgets.again_config(cfg, agent.task, leaves, scale)
    polished = parallel_map(search.polish_one, [(cfg, agent, s, method, tree, polish,
                                                 env_modules) for s in seeds],
                            n_jobs=processes(n_jobs, len(seeds)), progress=cfg.progress)
    trees = [tree, *polished]
    means = parallel_map(search.choice_mean, [(cfg, agent, t, choice, env_modules)
                                              for t in trees],
                         n_jobs=processes(n_jobs, len(trees)))
    best = max(range(1, len(trees)),
               key=lambda k: (means[k], -leaves_of(trees[k]), -k))
    return (trees[best] if means[best] > means[0] else None), tuple(means)


def again_length(cfg: Config, task: Task, leaves: int, *, seeds: int, scale: float,
                 n_jobs: int) -> float:
    """The least :func:`polish_again` runs, in episodes of one core's wall time."""
    config = budgets.search_config(cfg, task, leaves, scale)
    return (wall(seeds, n_jobs) * budgets.again_config(cfg, task, leaves, scale).episodes
            + wall(seeds + 1, n_jobs) * search.choice_episodes(config))


def spare_time(out: Ladder, step: Callable[..., Any], cfg: Config, agent: Agent,
               settings: Settings, replay: Replay | None = None) -> None:
    """Time left over, the ladder done or stopped before a step that would not fit: the searched
    BT nearest the target among those smaller than every BT that keeps it, polished again
    (:func:`polish_again`: one seed a core, seeds after the search's restarts), again
    while a polish fits, the last one improved it and it misses the target, at most
    ``AGAIN_ROUNDS`` times (replayed: the plan's seeds, whatever the cores). ``step``: the
    ladder's (:func:`ibt.engine.ladder.run_ladder`)."""
    from ibt.engine.ladder import eligible, keeps

    kept = min((c.bt_nodes for c in out.candidates if keeps(c, settings)), default=math.inf)
    below = [(c, c.search) for c in out.candidates if c.stage == "searched"
             and c.search is not None and eligible(c, settings) and c.bt_nodes < kept]
    if not below:
        return
    best, info = max(below, key=lambda pair: (pair[0].retention, -pair[0].bt_nodes))
    leaves, learner, tree = best.leaf_limit, best.learner, best.tree
    first, width = info.seeds[-1] + 1, max(1, settings.n_jobs)  # after the restarts

    def again(tree: Any, seeds: tuple[int, ...]) -> Any:
        better, means = polish_again(
            cfg, agent, tree, leaves, settings.seed, seeds,
            relational=get_learner(learner).combines_features,
            scale=settings.scale, n_jobs=settings.n_jobs, env_modules=settings.env_modules)
        out.notes.append(f"polished again at leaf limit {leaves} from seeds {list(seeds)}: "
                         f"{', '.join(f'{m:.2f}' for m in means[1:])} on the search's choice "
                         f"episodes against {means[0]:.2f} before; "
                         + ("the best kept" if better is not None else "none kept"))
        return better

    for _ in range(AGAIN_ROUNDS):
        if tree is None or keeps(best, settings):
            return
        name = f"polish again {learner} at {leaves} leaves"
        planned = replay.peek(name) if replay is not None else None
        seeds = planned.seeds if planned is not None else tuple(range(first, first + width))
        first += width
        tree = step(name, partial(again, tree, seeds), leaves, "polished", learner,
                    episodes=again_length(cfg, agent.task, leaves, seeds=width,
                                                 scale=settings.scale, n_jobs=settings.n_jobs),
                    seeds=seeds)
        best = out.candidates[-1] if tree is not None else best
