"""The structure-search stage: Imitation-BT+S, or +SR with relational tests (kinds ``evolve``,
``evolve-rel``), ``restarts`` seeds mapped over cores or a Dask cluster
(:func:`ibt.engine.parallel.parallel_map`), one of them chosen on held-out episodes of its own
(never the final ones) after the best of them are polished (a cached refinement,
:func:`ibt.engine.refine.refinement_cached`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ibt.cache.store import load_or_compute, tree_digest
from ibt.engine import budgets
from ibt.engine.agent import Agent
from ibt.engine.distil import import_env_modules
from ibt.engine.keys import leaves_of
from ibt.engine.measure import measure
from ibt.engine.parallel import parallel_map, processes, round_size, wall
from ibt.engine.refine import refinement_cached
from ibt.evaluate.rollouts import SELECTION_BLOCK, selection_seeds
from ibt.profiles import Config
from ibt.tasks.task import Task

#: held-out selection episodes that choose among a search's restarts (the run's block of
#: 10,000 seeds: the distillation's choice uses the first, refinement's 5,000 and up, the
#: search's own choice 7,000 and up)
RESTART_CHOICE_OFFSET = 8_500
#: the restarts' choice episodes, as a multiple of the search's own selection episodes (1,000
#: on LunarLander): with 100, the choice's standard error (5-9 there) was as large as the gaps
#: between restarts, and scoring a small tree on 1,000 episodes takes seconds
RESTART_CHOICE_FACTOR = 10
SEARCHED = "imitation-bt+s"  # the polish's source method: ibt.runs.front.STRUCTURE
SEARCHED_REL = "imitation-bt+sr"  # ibt.runs.relational_search.METHOD




@dataclass(frozen=True)
class SearchInfo:
    """How a search's restart was chosen: its seeds, the held-out episodes and their means."""

    seeds: tuple[int, ...]
    choice_episodes: int
    choice_means: tuple[float, ...]
    chosen: int  # index into seeds
    polished: tuple[int, ...] = ()  # the seeds polished, best choice mean first
    polished_means: tuple[float, ...] = ()  # theirs, polished, on the same episodes


def evolve_key(agent: Agent, sources: list[Any], config: Any, seed: int, relational: bool, *,
               scaled_weights: bool = False, agent_in_key: bool = True
               ) -> tuple[str, dict[str, Any]]:
    """The kind and key parameters of one structure search (see :func:`evolve_one`)."""
    params: dict[str, Any] = {"task": agent.task.key, "algo": agent.algo, "seed": seed,
                              "sources": [tree_digest(t) for t in sources],
                              "config": config.as_params()}
    if agent_in_key:
        params["expert_sha256"] = agent.digest
    if not relational:
        return "evolve", params
    from ibt.bt.linear import DEFAULT_WEIGHTS
    from ibt.refine.relational_structure import CANDIDATE_EPISODES

    params.update({"weights": [list(w) for w in DEFAULT_WEIGHTS],
                   "candidate_episodes": CANDIDATE_EPISODES,
                   **({"weight_scale": "spread"} if scaled_weights else {})})
    return "evolve-rel", params


def evolve_one(cfg: Config, agent: Agent, sources: list[Any], config: Any, seed: int,
               relational: bool, env_modules: tuple[str, ...] = (), *,
               scaled_weights: bool = False, agent_in_key: bool = True) -> Any:
    """One restart of the structure search (kinds ``evolve``, ``evolve-rel``); runs in a worker
    process too (the user's environment modules are imported there first).

    ``scaled_weights``: relational candidates' weights scaled to each pair's spreads.
    ``agent_in_key``: the agent's digest is part of the key (the pipeline's searches: its small
    seed trees may coincide for two agents); the committed studies' keys leave it out, as they
    were made: their seed trees, distilled at the task's budget from the agent, identify it."""
    import_env_modules(env_modules)
    task = agent.task
    kind, params = evolve_key(agent, sources, config, seed, relational,
                              scaled_weights=scaled_weights, agent_in_key=agent_in_key)

    def expert() -> Any:
        return agent.load() if config.use_expert else None

    def compute() -> Any:
        if relational:
            from ibt.refine.relational_structure import evolve_relational

            return evolve_relational(sources, task, config, seed, expert=expert(),
                                     scaled_weights=scaled_weights, progress=cfg.progress)
        from ibt.refine.structure import evolve

        return evolve(sources, task, config, seed, expert=expert(), progress=cfg.progress)

    return load_or_compute(kind, params, compute, cache_dir=cfg.cache_dir, codec="evolution",
                           refresh=cfg.refresh)


def search(cfg: Config, agent: Agent, sources: list[Any], leaves: int, seed: int, *,
           restarts: int = 1, relational: bool = False, scale: float = 1.0,
           n_jobs: int = 1, env_modules: tuple[str, ...] = (),
           next_round: Callable[[float], bool] | None = None,
           most: int | None = None, enough: float | None = None,
           exactly: int | None = None) -> tuple[Any, SearchInfo]:
    """The structure search at ``leaves`` from ``sources``: ``restarts`` seeds (``seed``,
    ``seed + 1``, ...), each restart's winner scored on the same held-out choice episodes
    (:data:`RESTART_CHOICE_FACTOR` times the search's own selection episodes); the best
    ``restarts`` polished (CMA-ES on thresholds, then free pruning), scored again, the best
    returned: a polish can move a return more than the restarts differ.

    Restarts run in rounds of ``n_jobs``, each cached on its own; a remainder joins the last
    full round (3 restarts on 2 cores: one round of 3 processes, 1.5 rounds' time; polishes
    likewise). ``next_round(seconds)``, given the last round's wall time, says whether another
    may start (the deadline): the choice is then among the restarts done, and a rerun with more
    time adds the others from the cache. With it, rounds of at most ``n_jobs`` go on past
    ``restarts`` up to ``most`` seeds while it allows, up to the first restart whose choice
    mean reaches ``enough`` (the target; the same seeds on any number of cores).
    ``exactly``: that many restarts, whatever the clock (a replayed plan's,
    :mod:`ibt.engine.plan`; ``next_round``, ``most`` and ``enough`` are then not used)."""
    task = agent.task
    config = budgets.search_config(cfg, task, leaves, scale)
    if exactly is not None:
        next_round, most, enough = None, exactly, None
    else:
        most = restarts if next_round is None else max(restarts, most or restarts)
    width = max(1, min(n_jobs, most))
    choice = selection_seeds(choice_episodes(config), seed, offset=RESTART_CHOICE_OFFSET)
    trees: list[Any] = []
    means: list[float] = []
    while len(trees) < most:
        size = round_size(restarts - len(trees), width)
        batch = range(seed + len(trees), seed + min(most, len(trees) + size))
        began = time.monotonic()
        records = parallel_map(evolve_one, [(cfg, agent, sources, config, s, relational,
                                             env_modules) for s in batch],
                               n_jobs=processes(n_jobs, len(batch)), progress=cfg.progress)
        seconds = time.monotonic() - began
        done = [_restart_winner(record, relational) for record in records]
        trees += done
        means += parallel_map(choice_mean, [(cfg, agent, tree, choice, env_modules)
                                            for tree in done],
                              n_jobs=processes(n_jobs, len(done)))
        reached = [i for i in range(restarts - 1, len(trees))
                   if enough is not None and means[i] >= enough]
        if reached:  # the restarts up to the first that reached it, whatever the round width
            del trees[reached[0] + 1:], means[reached[0] + 1:]
            break
        if next_round is not None and not next_round(seconds):
            break
    seeds = tuple(seed + r for r in range(len(trees)))
    finalists = sorted(range(len(trees)),
                       key=lambda i: (-means[i], leaves_of(trees[i]), i))[:restarts]
    method, settings = SEARCHED_REL if relational else SEARCHED, budgets.polish_config(cfg, config)
    polished = parallel_map(polish_one, [(cfg, agent, seeds[i], method, trees[i], settings,
                                          env_modules) for i in finalists],
                            n_jobs=processes(n_jobs, len(finalists)), progress=cfg.progress)
    scores = parallel_map(choice_mean, [(cfg, agent, tree, choice, env_modules)
                                        for tree in polished],
                          n_jobs=processes(n_jobs, len(polished)))
    best = max(range(len(finalists)),
               key=lambda k: (scores[k], -leaves_of(polished[k]), -finalists[k]))
    return polished[best], SearchInfo(seeds, len(choice), tuple(means), finalists[best],
                                      tuple(seeds[i] for i in finalists), tuple(scores))


def search_length(cfg: Config, task: Task, leaves: int, *, restarts: int, scale: float,
                  n_jobs: int) -> float:
    """The least a :func:`search` runs (its first round of restarts, their polishes and the
    choice episodes scoring them), in episodes of one core's wall time: what the ladder weighs
    against the time left before starting a first search."""
    config = budgets.search_config(cfg, task, leaves, scale)
    rounds = wall(round_size(restarts, max(1, min(n_jobs, restarts))), n_jobs)  # then polishes
    return rounds * (config.episodes + budgets.polish_config(cfg, config).episodes
                     + 2 * choice_episodes(config))


def choice_episodes(config: Any) -> int:
    """The held-out episodes that choose among a search's restarts (within the run's block)."""
    return min(RESTART_CHOICE_FACTOR * config.selection_episodes,
               SELECTION_BLOCK - RESTART_CHOICE_OFFSET)


def polish_one(cfg: Config, agent: Agent, seed: int, method: str, tree: Any, config: Any,
               env_modules: tuple[str, ...] = ()) -> Any:
    """One restart's winner polished (a cached refinement): its best tree. Runs in a worker
    process too."""
    from ibt.refine.relational import best_tree

    import_env_modules(env_modules)
    return best_tree(refinement_cached(cfg, agent.task, agent.algo, seed, method, tree, config))


def choice_mean(cfg: Config, agent: Agent, tree: Any, seeds: list[int],
                env_modules: tuple[str, ...] = ()) -> float:
    """A searched tree's mean return on held-out choice episodes
    (:func:`ibt.engine.measure.measure`, cached). Runs in a worker process too."""
    import_env_modules(env_modules)
    return measure(cfg, agent, tree, {}, seeds).mean


def _restart_winner(record: Any, relational: bool) -> Any:
    """A restart's best tree (a relational search's winner reads its relational record)."""
    if relational:
        from ibt.refine.relational_structure import winner

        return winner(record)
    return record.best_tree
