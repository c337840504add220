"""Refinement by return: raise a distilled tree's return while keeping it a small axis-aligned tree.

Imitation copies the expert's decisions, and a small tree copies them imperfectly exactly where
it matters (LunarLander: a 32-leaf tree keeps about half of the expert). The paper names the
missing step as future work: refine the distilled policy online. This module does it on the
environment's return, never on the expert's labels, with three moves that keep the tree's shape
(or make it smaller):

* **thresholds** by CMA-ES (the ``cma`` package: a well-kept, standard optimiser for a few dozen
  continuous, noisy parameters that needs no gradients and is invariant to rescaling; nevergrad
  and optuna wrap the same method with more machinery). Each threshold moves in units of the
  spread of its feature over the states the tree visits;
* **leaf actions** by a greedy sweep: every single-leaf change is tried and the best one kept
  when it beats the incumbent on the same episodes;
* **pruning**: every split is tried fixed to either side (which removes the other subtree), and
  the best such cut is kept while it costs no return beyond a tolerance — or, when the tree has
  more leaves than ``max_leaves``, until it is small enough (stage ``prune``; stage ``shrink``
  only cuts down to ``max_leaves``, so that a tree is tuned before any cut that is optional).

Every candidate is scored on *refinement* episodes (:data:`ibt.evaluate.rollouts.REFINE_SEED_BASE`),
disjoint from the distillation's training and selection episodes and from the final evaluation.
All members of one comparison are scored on the same episodes (common random numbers), and each
comparison draws fresh ones, so a lucky seed set cannot be climbed. Candidates of one structure
run side by side in one batch of environments: the tree is decided on the whole batch at once.
The stages' results, the source tree included, are finally compared on held-out selection
episodes (:data:`ibt.evaluate.rollouts.REFINE_SELECTION_OFFSET`), and the best is returned.

Deterministic given the seed: episode seeds are counted, CMA-ES samples from a seeded
``numpy.random.Generator``, and the budget is counted in episodes, not seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, Generic, Protocol, Self, TypeVar

import numpy as np
from sklearn.tree import DecisionTreeClassifier
from tqdm import tqdm

from ibt.evaluate.rollouts import (
    REFINE_SEED_BASE,
    REFINE_SELECTION_OFFSET,
    rollout,
    selection_seeds,
    visited_features,
)
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.settings import REFINE_STAGES, RefineConfig
from ibt.tasks.task import Task

STAGES = REFINE_STAGES


def task_config(task: Task, **overrides: Any) -> RefineConfig:
    """The task's refinement budget (its catalogue entry's ``refine``) with ``overrides``; a
    leaf limit without a cutting stage gets ``shrink`` first."""
    from dataclasses import replace

    config = replace(task.refine, **overrides)
    if config.max_leaves is not None and not {"shrink", "prune"} & set(config.stages):
        config = replace(config, stages=("shrink", *config.stages))
    return config


Candidate = TypeVar("Candidate")


@dataclass
class RefinementRecord(Generic[Candidate]):
    """A refinement run's record, whatever its candidates are (:class:`TreeArrays` here,
    command trees in :mod:`ibt.refine.commands`): each stage's result and the chosen one. The
    fields, in this order, are the cached payloads' (the ``refinement`` codec, the command
    refinement's JSON document)."""

    task: str
    seed: int
    config: dict[str, Any]
    stages: list[dict[str, Any]] = field(default_factory=list)
    candidates: list[Candidate] = field(default_factory=list)  # [source, after each stage]
    best_index: int = 0
    selection_means: list[float] = field(default_factory=list)  # per candidate, held out
    episodes: int = 0  # refinement episodes used (selection episodes not included)
    steps: int = 0  # environment steps of those episodes
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0  # this process's CPU time (one core), selection included

    @property
    def best(self) -> Candidate:
        return self.candidates[self.best_index]

    def to_doc(self) -> dict[str, Any]:
        """Plain JSON data (a ``json`` cache payload), for candidates that have ``to_doc``."""
        doc = {f.name: getattr(self, f.name) for f in fields(self)}
        return {**doc, "candidates": [c.to_doc() for c in self.candidates]}  # type: ignore[attr-defined]

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> Self:
        """The record of :meth:`to_doc`'s document (:meth:`candidate_from_doc` reads each
        candidate)."""
        return cls(**{**doc, "candidates": [cls.candidate_from_doc(c)
                                            for c in doc["candidates"]]})

    @staticmethod
    def candidate_from_doc(doc: dict[str, Any]) -> Candidate:
        raise NotImplementedError


@dataclass
class Refinement(RefinementRecord[TreeArrays]):
    """A tree refinement's record: each stage's result and the chosen tree."""

    @property
    def best_tree(self) -> DecisionTreeClassifier:
        """The chosen tree as a scikit-learn classifier (what synthesis reads)."""
        return self.best.to_sklearn()


class ThresholdSets:
    """Threshold sets of one tree structure, walked in one batch: row ``i`` goes down the tree
    with member ``members[i]``'s thresholds (float32 features widened to float64, as
    scikit-learn). What the leaves hold is the subclass's: actions (:class:`Population`),
    command values (:class:`ibt.refine.commands.CommandPopulation`)."""

    def __init__(self, structure: TreeArrays, thresholds: np.ndarray):
        self.structure = structure
        self.thresholds = np.atleast_2d(np.asarray(thresholds, dtype=np.float64))
        self.feature = np.maximum(structure.feature, 0)
        self.is_leaf = structure.is_leaf
        self.depth = structure.depth()

    def __len__(self) -> int:
        return len(self.thresholds)

    def leaves(self, features: np.ndarray, members: np.ndarray) -> np.ndarray:
        """The leaf each row reaches in its member's tree."""
        x = np.asarray(features, dtype=np.float32).astype(np.float64)
        rows = np.arange(len(x))
        node = np.zeros(len(x), dtype=np.int64)
        for _ in range(self.depth):
            go_left = x[rows, self.feature[node]] <= self.thresholds[members, node]
            nxt = np.where(go_left, self.structure.left[node], self.structure.right[node])
            node = np.where(self.is_leaf[node], node, nxt)
        return node


class Population(ThresholdSets):
    """Parameter sets (thresholds, leaf actions) of one tree structure, decided in one batch."""

    def __init__(self, structure: TreeArrays, thresholds: np.ndarray, actions: np.ndarray):
        super().__init__(structure, thresholds)
        self.actions = np.atleast_2d(np.asarray(actions, dtype=np.int64))

    def decide(self, features: np.ndarray, members: np.ndarray) -> np.ndarray:
        return self.actions[members, self.leaves(features, members)]

    def member(self, i: int) -> TreeArrays:
        return self.structure.with_parameters(self.thresholds[i], self.actions[i])


class Batch(Protocol):
    """Trees decided side by side: row ``i`` is decided by member ``members[i]``
    (:class:`Population` here, trees of different shapes in :mod:`ibt.refine.forest`)."""

    def __len__(self) -> int: ...

    def decide(self, features: np.ndarray, members: np.ndarray) -> np.ndarray: ...


class RefineEpisodes:
    """Hands out fresh refinement episode seeds and counts what was spent: episodes, steps,
    and the run's wall and CPU seconds since it was opened (:meth:`elapsed`)."""

    def __init__(self, task: Task, seed: int, config: RefineConfig, bar: Any) -> None:
        self.task = task
        self.config = config
        self.next_seed = REFINE_SEED_BASE + 1_000_000 * seed
        self.used = 0
        self.steps = 0
        self.bar = bar
        self.start, self.cpu_start = time.perf_counter(), time.process_time()

    @classmethod
    def opened(cls, task: Task, seed: int, config: Any, what: str, progress: bool) -> Self:
        """A run's episodes, its progress bar (``what``: the run's name) counting them."""
        bar = tqdm(total=config.episodes, desc=f"{what} {task.name} s{seed}", unit="ep",
                   disable=not progress, leave=False)
        return cls(task, seed, config, bar)

    def elapsed(self) -> tuple[float, float]:
        """Wall and CPU (this process, one core) seconds since the run was opened."""
        return time.perf_counter() - self.start, time.process_time() - self.cpu_start

    @property
    def left(self) -> int:
        return self.config.episodes - self.used

    def fresh(self, n: int) -> list[int]:
        seeds = list(range(self.next_seed, self.next_seed + n))
        self.next_seed += n
        return seeds

    def score(self, population: Batch, seeds: list[int], *, count: bool = True
              ) -> np.ndarray:
        """Returns ``(members, episodes)``: every member on every seed."""
        k = len(seeds)
        all_seeds = [s for _ in range(len(population)) for s in seeds]

        def act(obs: np.ndarray, episodes: np.ndarray) -> np.ndarray:
            return population.decide(self.task.features(obs), episodes // k)

        result = rollout(self.task, act, all_seeds, n_envs=self.config.n_envs, indexed=True)
        if count:
            self.used += len(all_seeds)
            self.steps += int(result.lengths.sum())
            self.bar.update(len(all_seeds))
        return result.returns.reshape(len(population), k)


def feature_spread(task: Task, arrays: TreeArrays, episodes: RefineEpisodes) -> np.ndarray:
    """Each feature's standard deviation over the states the tree visits (a CMA-ES scale)."""
    policy = Population(arrays, arrays.threshold, arrays.action)
    return visited_spread(task, lambda x: policy.decide(x, np.zeros(len(x), dtype=np.int64)),
                          episodes)


def visited_spread(task: Task, decide: Callable[[np.ndarray], np.ndarray],
                   episodes: RefineEpisodes) -> np.ndarray:
    """Each feature's standard deviation over the states a policy visits (``decide``: feature
    rows -> actions) on 8 fresh episodes, floored at a thousandth of the feature's box: the
    unit in which CMA-ES moves a threshold on that feature."""
    x = visited_features(task, decide, episodes.fresh(8), n_envs=8).astype(np.float64)
    box = np.asarray(task.high, dtype=np.float64) - np.asarray(task.low, dtype=np.float64)
    floor = np.where(np.isfinite(box) & (box > 0), 1e-3 * box, 1e-3)
    return np.maximum(x.std(axis=0), floor)


def cma_search(n_params: int, config: RefineConfig, episodes: RefineEpisodes,
               rng: np.random.Generator, population_of: Callable[[np.ndarray], Any]
               ) -> tuple[np.ndarray | None, dict]:
    """CMA-ES on ``n_params`` parameters in their own units (``population_of`` maps a batch of
    parameter vectors to a population that :meth:`RefineEpisodes.score` rolls out), generations of
    ``cma_episodes`` fresh episodes while the budget lasts; then the incumbent (all zeros),
    CMA-ES's mean and its best sample are compared on the same fresh episodes. Returns the
    winner's parameters (None: no generation ran) and what happened."""
    import cma

    options = {"seed": np.nan, "randn": lambda lam, n: rng.standard_normal((lam, n)),
               "verbose": -9, "verb_log": 0, "verb_disp": 0, "tolflatfitness": 10**9,
               "tolfun": 0, "tolx": 0, "tolstagnation": 10**9}
    if config.cma_popsize:
        options["popsize"] = config.cma_popsize
    es = cma.CMAEvolutionStrategy(np.zeros(n_params), config.cma_sigma, options)
    generations = 0
    history: list[tuple[float, float]] = []  # per generation: population mean, best member
    while generations < config.cma_generations:
        if episodes.left < es.popsize * config.cma_episodes:
            break
        z = np.asarray(es.ask())
        returns = episodes.score(population_of(z), episodes.fresh(config.cma_episodes))
        member_means = returns.mean(axis=1)
        es.tell(list(z), list(-member_means))
        history.append((round(float(member_means.mean()), 2), round(float(member_means.max()), 2)))
        generations += 1
        episodes.bar.set_postfix(generation=generations, mean=history[-1][0],
                                 best=history[-1][1])
    if generations == 0:
        return None, {"generations": 0}
    contenders = np.vstack([np.zeros(n_params), es.mean, es.best.x])
    k = config.sweep_episodes
    if episodes.left >= 3 * k:
        means = episodes.score(population_of(contenders), episodes.fresh(k)).mean(axis=1)
        pick = int(np.argmax(means))
    else:
        means, pick = np.full(3, np.nan), 1
    return contenders[pick], {"generations": generations, "history": history,
                              "picked": ("incumbent", "mean", "best sample")[pick],
                              "compare_means": [round(float(m), 3) for m in means]}


def _cma_stage(arrays: TreeArrays, spread: np.ndarray, config: RefineConfig,
               episodes: RefineEpisodes, rng: np.random.Generator) -> tuple[TreeArrays, dict]:
    """CMA-ES on the tree's thresholds, each in its feature's spread (:func:`cma_search`)."""
    splits = np.flatnonzero(~arrays.is_leaf)
    if len(splits) == 0:
        return arrays, {"generations": 0}
    base = arrays.threshold.copy()
    scale = spread[arrays.feature[splits]]

    def population_of(z: np.ndarray) -> Population:
        out = np.repeat(base[None, :], len(z), axis=0)
        out[:, splits] = base[splits] + np.asarray(z) * scale
        return Population(arrays, out, np.repeat(arrays.action[None, :], len(z), axis=0))

    best, info = cma_search(len(splits), config, episodes, rng, population_of)
    if best is None:
        return arrays, info
    return population_of(best[None, :]).member(0), info


def _confirmed(incumbent: TreeArrays, candidate: TreeArrays, config: RefineConfig,
               episodes: RefineEpisodes, tolerance: float | None = None) -> bool:
    """Does ``candidate`` hold up against ``incumbent`` on fresh episodes (twice a sweep's)?

    ``tolerance`` None: it must score strictly higher; else at most ``tolerance`` lower.

    The best of many candidates on one episode set is flattered by its luck (the winner's
    curse); a second, independent comparison keeps only changes that were not luck.
    """
    k = 2 * config.sweep_episodes
    if episodes.left < 2 * k:
        return False
    if incumbent.node_count != candidate.node_count or not np.array_equal(
            incumbent.feature, candidate.feature):  # different structures: score separately
        seeds = episodes.fresh(k)
        old = episodes.score(Population(incumbent, incumbent.threshold, incumbent.action),
                             seeds).mean()
        new = episodes.score(Population(candidate, candidate.threshold, candidate.action),
                             seeds).mean()
    else:
        pair = Population(incumbent, np.vstack([incumbent.threshold, candidate.threshold]),
                          np.vstack([incumbent.action, candidate.action]))
        old, new = episodes.score(pair, episodes.fresh(k)).mean(axis=1)
    return bool(new > old) if tolerance is None else bool(new >= old - tolerance)


def _leaf_stage(arrays: TreeArrays, config: RefineConfig, episodes: RefineEpisodes
                ) -> tuple[TreeArrays, dict]:
    changes = 0
    tried = 0
    for _ in range(config.sweep_rounds):
        leaves = np.flatnonzero(arrays.is_leaf)
        options = [(leaf, a) for leaf in leaves for a in range(arrays.n_actions)
                   if a != arrays.action[leaf]]
        if not options:
            break
        if episodes.left < (len(options) + 1) * config.sweep_episodes:
            break
        actions = np.repeat(arrays.action[None, :], len(options) + 1, axis=0)
        for i, (leaf, a) in enumerate(options, start=1):
            actions[i, leaf] = a
        population = Population(arrays, np.repeat(arrays.threshold[None, :], len(actions), 0),
                                actions)
        means = episodes.score(population, episodes.fresh(config.sweep_episodes)).mean(axis=1)
        best = int(np.argmax(means))
        tried += 1
        if best == 0 or means[best] <= means[0]:
            break
        if not _confirmed(arrays, population.member(best), config, episodes):
            break
        arrays = population.member(best)
        changes += 1
    return arrays, {"changes": changes, "sweeps": tried}


def prune_stage(arrays: TreeArrays, config: RefineConfig, episodes: RefineEpisodes,
                optional: bool = True) -> tuple[TreeArrays, dict]:
    """Cut subtrees: down to ``max_leaves`` by least loss, then (``optional``) while a cut
    costs nothing."""
    forced_cuts = cuts = 0
    while True:
        arrays = arrays.simplified()
        forced = config.max_leaves is not None and arrays.n_leaves > config.max_leaves
        if not forced and (not optional or cuts >= config.sweep_rounds):
            break
        splits = np.flatnonzero(~arrays.is_leaf)
        if len(splits) == 0:
            break
        need = (2 * len(splits) + 1) * config.sweep_episodes
        if episodes.left < need and not forced:
            break
        thresholds = np.repeat(arrays.threshold[None, :], 2 * len(splits) + 1, axis=0)
        for i, node in enumerate(splits):
            thresholds[1 + 2 * i, node] = np.inf  # keep the left subtree
            thresholds[2 + 2 * i, node] = -np.inf  # keep the right subtree
        population = Population(arrays, thresholds,
                                np.repeat(arrays.action[None, :], len(thresholds), axis=0))
        k = config.sweep_episodes if episodes.left >= need else 1
        means = episodes.score(population, episodes.fresh(k)).mean(axis=1)
        sizes = np.array([population.member(i).simplified().n_leaves
                          for i in range(len(population))])
        if forced:  # the least harmful cut, removing as little as possible on ties, and
            # never one that undershoots the limit when another does not
            order = sorted(range(1, len(population)), key=lambda i: (-means[i], -sizes[i], i))
            fitting = [i for i in order if sizes[i] >= config.max_leaves]
            order = fitting or order
        else:  # a free cut: the best, the smallest on ties
            order = sorted(range(1, len(population)), key=lambda i: (-means[i], sizes[i], i))
        best = order[0]
        candidate = population.member(best).simplified()
        if forced:
            arrays = candidate
            forced_cuts += 1
            continue
        if means[best] < means[0] - config.prune_tolerance or not _confirmed(
                arrays, candidate, config, episodes, tolerance=config.prune_tolerance):
            break
        arrays = candidate
        cuts += 1
    return arrays.simplified(), {"forced_cuts": forced_cuts, "cuts": cuts}


def refine(tree: DecisionTreeClassifier | TreeArrays, task: Task, config: RefineConfig,
           seed: int = 0, *, progress: bool = True) -> Refinement:
    """Refine ``tree`` on ``task``'s return; see the module docstring."""
    source = tree if isinstance(tree, TreeArrays) else TreeArrays.from_sklearn(tree)
    source = source.simplified()
    if source.n_features != task.n_features:
        raise ValueError(f"the tree reads {source.n_features} features, {task.name} has "
                         f"{task.n_features}")
    rng = np.random.default_rng(seed)
    record = Refinement(task.name, seed, config.as_params(), candidates=[source])
    episodes = RefineEpisodes.opened(task, seed, config, "refine", progress)
    bar = episodes.bar
    spread = feature_spread(task, source, episodes)
    current = source
    for name in config.stages:
        before = current.n_leaves
        if name == "cma":
            current, info = _cma_stage(current, spread, config, episodes, rng)
        elif name == "leaves":
            current, info = _leaf_stage(current, config, episodes)
        else:
            current, info = prune_stage(current, config, episodes, optional=name == "prune")
        current = current.simplified()
        record.candidates.append(current)
        record.stages.append({"stage": name, "leaves_before": before,
                              "leaves": current.n_leaves, "episodes_used": episodes.used,
                              **info})
        bar.set_postfix(stage=name, leaves=current.n_leaves)
    bar.close()
    # the stages' results, side by side on held-out selection episodes
    structures = record.candidates
    scores = held_out_means(episodes, [Population(a, a.threshold, a.action) for a in structures],
                            config, seed)
    eligible = [i for i, a in enumerate(structures)
                if config.max_leaves is None or a.n_leaves <= config.max_leaves]
    if not eligible:
        eligible = [len(structures) - 1]
    record.best_index = max(eligible, key=lambda i: (scores[i], -structures[i].n_leaves, -i))
    return close_record(record, scores, episodes)


def held_out_means(episodes: RefineEpisodes, populations: list[Any], config: RefineConfig,
                   seed: int) -> list[float]:
    """Each candidate's mean return on the run's held-out selection episodes (disjoint from
    its refinement episodes and the final evaluation; not counted in the budget)."""
    held_out = selection_seeds(config.selection_episodes, seed, offset=REFINE_SELECTION_OFFSET)
    return [float(episodes.score(p, held_out, count=False).mean()) for p in populations]


Record = TypeVar("Record", bound=RefinementRecord)


def close_record(record: Record, scores: list[float], episodes: RefineEpisodes) -> Record:
    """A refinement's record completed: its selection means and what the run cost (episodes,
    steps, wall and CPU seconds since ``episodes`` was opened)."""
    record.selection_means = scores
    record.episodes, record.steps = episodes.used, episodes.steps
    record.wall_seconds, record.cpu_seconds = episodes.elapsed()
    return record
