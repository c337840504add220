"""The method's stages for one agent, each a cached function (:mod:`ibt.cache.store`).

A stage takes the :class:`~ibt.engine.agent.Agent` and plain settings and returns a tree:

* :func:`distil`: the interactive loop at a leaf limit with one of three learners, ``axis``
  (CART), ``relational`` (splits on ``w1 * x_i + w2 * x_j``) or ``box`` (a regression tree
  whose leaves are merged into named commands, :mod:`ibt.synth.commands`);
* :func:`refine`: refinement by return (thresholds, leaves, pruning; commands' values too);
* :func:`search`: the structure search by return (Imitation-BT+S, or +SR with relational
  tests), ``restarts`` seeds mapped over cores or a Dask cluster
  (:func:`ibt.engine.parallel.parallel_map`), one of them chosen on held-out episodes of
  its own (never the final ones) after the best of them are polished;
* :func:`measure`: a tree's returns on a block of held-out episodes (its verified BTs, every
  registered synthesiser's, are the synthesis stage's: :mod:`ibt.engine.synthesis`).

Keys are the project's: the kinds and parameters of the grid's and the front's homes, with
the agent's digest (``expert_sha256``: a checkpoint's bytes, or a callable's module and name)
wherever the agent decides what a stage computes. Budgets are in episodes, never seconds, so a
cached result does not depend on the machine.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from ibt.cache.store import load_or_compute, tree_digest
from ibt.engine import budgets
from ibt.engine.agent import Agent
from ibt.engine.parallel import parallel_map, processes, round_size, wall
from ibt.evaluate.rollouts import (
    FINAL_SEED_BASE,
    SELECTION_BLOCK,
    ReturnStats,
    rollout,
    selection_seeds,
)
from ibt.profiles import Config
from ibt.tasks.task import Task

LEARNERS = ("axis", "relational", "box")
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


@dataclass
class Returns(ReturnStats):
    """Episode returns of one policy on a block of held-out episodes (consecutive seeds)."""

    returns: list[float]
    first_seed: int
    lengths: list[int] | None = None  # every episode's steps (entries from before: unknown)
    seconds: float | None = None  # the rollout's wall time, where rolled out now (not cached)


def held_out(n: int, block: int) -> list[int]:
    """Block 0: the choice episodes (the final-evaluation seeds); block 1: confirmation."""
    return [FINAL_SEED_BASE + block * n + i for i in range(n)]


def returns_of(cfg: Config, task: Any, what: dict[str, Any], act: Any, seeds: list[int]
               ) -> Returns:
    """A policy's returns on ``seeds`` (consecutive), cached under ``what`` (``bt``: a BT's
    digest, ``tree``: a tree's, else an agent's or the random policy's identity) as the kind
    ``returns``: every episode's return and length (steps), where the grid's evaluation kinds
    keep summaries; rolled out now, it also tells the rollout's wall time (the ladder's pace)."""
    params = {"task": task.key, "episodes": len(seeds), "first_seed": seeds[0], **what}
    now: list[Returns] = []

    def compute() -> dict[str, Any]:
        now.append(rolled(task, act, seeds))
        return {"returns": now[0].returns, "lengths": now[0].lengths}

    doc = load_or_compute("returns", params, compute, cache_dir=cfg.cache_dir, codec="json",
                          refresh=cfg.refresh)
    lengths = doc.get("lengths")
    return Returns(list(doc["returns"]), seeds[0], list(lengths) if lengths else None,
                   now[0].seconds if now else None)


def rolled(task: Any, act: Callable[[], Any], seeds: list[int]) -> Returns:
    """A policy's returns on ``seeds`` rolled out now, not cached, with their wall time."""
    began = time.perf_counter()
    done = rollout(task, act(), seeds)
    return Returns([float(r) for r in done.returns], seeds[0], [int(n) for n in done.lengths],
                   time.perf_counter() - began)


def doc_digest(doc: Any) -> str:
    """The identity of a plain-data document (a command tree's arrays)."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def tree_key(tree: Any) -> str:
    """The identity of any tree a stage returns (classifier, relational or command tree)."""
    from ibt.refine.commands import CommandArrays

    return doc_digest(tree.to_doc()) if isinstance(tree, CommandArrays) else tree_digest(tree)


def bt_digest(bt: Any) -> str:
    """A BT's identity in cache keys: the digest of its JSON document."""
    return hashlib.sha256(bt.to_json().encode()).hexdigest()[:16]


def smallest_bt(bts: dict[str, Any]) -> str:
    """The synthesiser whose BT has the fewest nodes (ties: the earlier one, in the order the
    BTs were made, the registry's): the one "smallest BT" rule of the grid, the front, the
    continuous study and the pipeline."""
    names = list(bts)
    return min(names, key=lambda m: (bts[m].node_count, names.index(m)))


def leaves_of(tree: Any) -> int:
    from ibt.refine.commands import CommandArrays

    return int(tree.n_leaves if isinstance(tree, CommandArrays) else tree.get_n_leaves())


# --- distil -----------------------------------------------------------------------------------


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
    _import_modules(env_modules)
    run = distillation(cfg, agent, seed, learner, max_leaf_nodes=leaves)
    if learner == "box":
        from ibt.refine.commands import CommandArrays

        return CommandArrays.from_doc(commands(cfg, agent, run["tree"], seed)["arrays"])
    return run.best_tree


def box_method(agent: Agent) -> str:
    """Critic-weighted imitation for SAC and TD3 agents (their critic scores any action);
    plain DAgger for the others."""
    return "imitation-bt" if agent.algo in ("sac", "td3") else "dagger"


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
        scale = rollout(task, agent.load().act, seeds).mean - rollout(
            task, agent.random_act(seed), seeds).mean
        chosen, rows = choose_commands(regressor_from_doc(tree_doc), task, seeds,
                                       scale=scale, tolerance=budgets.COMMAND_TOLERANCE, seed=seed)
        return {"arrays": CommandArrays.from_command_tree(chosen).to_doc(), "rows": rows,
                "scale": scale}

    return load_or_compute("box-commands", params, choose, cache_dir=cfg.cache_dir,
                           codec="json", refresh=cfg.refresh)


# --- refine -----------------------------------------------------------------------------------


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


def refine(cfg: Config, agent: Agent, tree: Any, seed: int, scale: float = 1.0,
           episodes: int | None = None, env_modules: tuple[str, ...] = ()) -> Any:
    """``tree`` refined by return (kinds ``refine``, ``refine-rel``, ``box-refine``): the
    refinement's chosen tree. Runs in a worker process too (as :func:`distil`)."""
    from ibt.refine.commands import CommandArrays

    _import_modules(env_modules)
    task = agent.task
    if isinstance(tree, CommandArrays):
        config = budgets.scaled_refine_config(cfg, task, scale, episodes, commands=True)
        return command_refinement(cfg, agent, tree, seed, config).best
    from ibt.distill.relational import RelationalTreeClassifier
    from ibt.refine.relational import best_tree

    source = budgets.RELATIONAL if isinstance(tree, RelationalTreeClassifier) else "imitation-bt"
    return best_tree(refinement_cached(cfg, task, agent.algo, seed, source, tree,
                                       budgets.scaled_refine_config(cfg, task, scale,
                                                                    episodes)))


# --- structure search -------------------------------------------------------------------------


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
    _import_modules(env_modules)
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


def _import_modules(modules: tuple[str, ...]) -> None:
    from ibt.tasks.catalogue import import_env_module

    for module in modules:
        import_env_module(module)


def search(cfg: Config, agent: Agent, sources: list[Any], leaves: int, seed: int, *,
           restarts: int = 1, relational: bool = False, scale: float = 1.0,
           n_jobs: int = 1, env_modules: tuple[str, ...] = (),
           next_round: Callable[[float], bool] | None = None,
           most: int | None = None, enough: float | None = None) -> tuple[Any, SearchInfo]:
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
    mean reaches ``enough`` (the target; the same seeds on any number of cores)."""
    task = agent.task
    config = budgets.search_config(cfg, task, leaves, scale)
    most = restarts if next_round is None else max(restarts, most or restarts)
    quiet = replace(cfg, progress=cfg.progress and most == 1)
    width = max(1, min(n_jobs, most))
    choice = selection_seeds(choice_episodes(config), seed, offset=RESTART_CHOICE_OFFSET)
    trees: list[Any] = []
    means: list[float] = []
    while len(trees) < most:
        size = round_size(restarts - len(trees), width)
        batch = range(seed + len(trees), seed + min(most, len(trees) + size))
        began = time.monotonic()
        records = parallel_map(evolve_one, [(quiet, agent, sources, config, s, relational,
                                             env_modules) for s in batch],
                               n_jobs=processes(n_jobs, len(batch)))
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
    polished = parallel_map(polish_one, [(quiet, agent, seeds[i], method, trees[i], settings,
                                          env_modules) for i in finalists],
                            n_jobs=processes(n_jobs, len(finalists)))
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

    _import_modules(env_modules)
    return best_tree(refinement_cached(cfg, agent.task, agent.algo, seed, method, tree, config))


def choice_mean(cfg: Config, agent: Agent, tree: Any, seeds: list[int],
                env_modules: tuple[str, ...] = ()) -> float:
    """A searched tree's mean return on held-out choice episodes (:func:`measure`, cached).
    Runs in a worker process too."""
    _import_modules(env_modules)
    return measure(cfg, agent, tree, {}, seeds).mean


def _restart_winner(record: Any, relational: bool) -> Any:
    """A restart's best tree (a relational search's winner reads its relational record)."""
    if relational:
        from ibt.refine.relational_structure import winner

        return winner(record)
    return record.best_tree


# --- measure ----------------------------------------------------------------------------------


def measure(cfg: Config, agent: Agent, tree: Any, bts: dict[str, Any], seeds: list[int]
            ) -> Returns:
    """The tree's returns on ``seeds`` (every BT of it decides as it does); a command tree is
    rolled out through its smallest BT (the command table is the BT's)."""
    return returns_of(cfg, agent.task, *policy(agent, tree, bts), seeds)


def policy(agent: Agent, tree: Any, bts: dict[str, Any]
           ) -> tuple[dict[str, Any], Callable[[], Any]]:
    """How a tree is measured: its identity in the cache, and its policy's maker."""
    from ibt.evaluate.policies import TreePolicy
    from ibt.refine.commands import CommandArrays

    task = agent.task
    if isinstance(tree, CommandArrays):
        from ibt.synth.commands import CommandBTPolicy

        bt = bts[smallest_bt(bts)]
        return {"bt": bt_digest(bt)}, lambda: CommandBTPolicy(task, bt).act
    return {"tree": tree_key(tree)}, lambda: TreePolicy(task, tree).act
