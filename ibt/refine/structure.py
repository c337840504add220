"""Structure search by return: evolve a small tree's splits, features, thresholds and leaves.

Refinement by return (:mod:`ibt.refine.by_return`, Imitation-BT+) keeps a distilled tree's
structure: it tunes thresholds and leaf actions and cuts subtrees. MENS-DT-RL (Costa et al.,
Artificial Intelligence 2024) evolves the structure itself on return and reaches smaller trees
that land better. This module does that, seeded with distilled trees and helped by the expert
where reward alone is slow:

* **a (mu + lambda) evolution strategy** over trees of at most ``max_leaves`` leaves. Each
  generation every parent makes children by one mutation; parents and children are scored side
  by side on the *same fresh* refinement episodes (common random numbers: a comparison is
  between trees, not between episode draws, and no seed set can be climbed) and the best
  ``mu`` survive (fewer leaves break ties). Parents are re-scored every generation, so a lucky
  score does not survive on luck.
* **mutations** (:mod:`ibt.refine.structure_mutations`): thresholds, features, leaf actions,
  cuts and growth; with **the expert's help** (optional) growth fits the split that best
  separates the expert's labels on states the current best tree visits, and a leaf can take
  the expert's action there.
* the run's final parents and the best of each generation are compared on held-out selection
  episodes (disjoint from the refinement episodes and from the final evaluation), and the best
  is returned.

Deterministic in the seed; the budget is counted in episodes. Trees of different shapes run
side by side in one batch of environments (:class:`ibt.refine.forest.Forest`), the trees
decided on the batch.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.evaluate.rollouts import REFINE_SEED_BASE, rollout, selection_seeds
from ibt.refine.by_return import RefineEpisodes, prune_stage
from ibt.refine.forest import Forest
from ibt.refine.structure_mutations import TreeMutator, arrays, nested
from ibt.refine.tree_arrays import TreeArrays
from ibt.tasks.settings import EvolveConfig
from ibt.tasks.task import Task

#: Held-out selection episodes of the structure search (the run's block of 10,000 seeds:
#: refinement's own choice uses 5,000 and up, the distillation's below)
EVOLVE_SELECTION_OFFSET = 7_000
EVOLVE_SEED_BASE = REFINE_SEED_BASE + 500_000  # its refinement episodes: apart from by_return's


@dataclass
class Evolution:
    """A structure search's record: the chosen tree, what was tried, what it cost."""

    task: str
    seed: int
    config: dict[str, Any]
    sources: list[TreeArrays] = field(default_factory=list)
    finalists: list[TreeArrays] = field(default_factory=list)
    selection_means: list[float] = field(default_factory=list)
    best_index: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)  # per generation
    episodes: int = 0
    steps: int = 0
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0
    # environment steps per CPU-second: the search's (every step its CPU paid for, the held-out
    # choice's too, though only the budget's count in ``steps``), and a uniform random policy's
    # stepped by the same batched rollout in the same run (the physical limit of this machine)
    steps_per_second: float = 0.0
    random_steps_per_second: float = 0.0

    @property
    def best(self) -> TreeArrays:
        return self.finalists[self.best_index]

    @property
    def best_tree(self) -> DecisionTreeClassifier:
        return self.best.to_sklearn()


class _Budget(RefineEpisodes):
    """Fresh refinement episodes of the search (its own seed block), counted; trees of any
    shapes are scored side by side as a :class:`Forest`."""

    def __init__(self, task: Task, seed: int, config: EvolveConfig, bar: Any) -> None:
        super().__init__(task, seed, config, bar)  # type: ignore[arg-type]
        self.next_seed = EVOLVE_SEED_BASE + 1_000_000 * seed
        self.uncounted_steps = 0  # stepped outside the budget (the held-out choice)

    def score_trees(self, trees: list[TreeArrays], seeds: list[int], *, count: bool = True
                    ) -> np.ndarray:
        """``(trees, episodes)`` returns, every tree on every seed (as
        :meth:`ibt.refine.by_return.RefineEpisodes.score`, reading only the tested columns)."""
        forest = Forest(trees)
        read = forest.reader(self.task)
        k = len(seeds)
        all_seeds = [s for _ in range(len(trees)) for s in seeds]

        def act(obs: np.ndarray, episodes: np.ndarray) -> np.ndarray:
            return forest.decide_columns(read(obs), episodes // k)

        result = rollout(self.task, act, all_seeds, n_envs=self.config.n_envs, indexed=True)
        if count:
            self.used += len(all_seeds)
            self.steps += int(result.lengths.sum())
            self.bar.update(len(all_seeds))
        else:
            self.uncounted_steps += int(result.lengths.sum())
        return result.returns.reshape(len(trees), k)

    def visit(self, tree: TreeArrays, n_episodes: int) -> np.ndarray:
        """States the tree visits on ``n_episodes`` fresh episodes (counted)."""
        states: list[np.ndarray] = []
        forest = Forest([tree])

        def act(obs: np.ndarray) -> np.ndarray:
            x = self.task.features(obs)
            states.append(x)
            return forest.decide(x, np.zeros(len(x), dtype=np.int64))

        result = rollout(self.task, act, self.fresh(n_episodes), n_envs=n_episodes)
        self.used += n_episodes
        self.steps += int(result.lengths.sum())
        self.bar.update(n_episodes)
        return np.concatenate(states).astype(np.float32)


def _shrink(tree: TreeArrays, config: EvolveConfig, budget: _Budget) -> TreeArrays:
    """A seed tree larger than the leaf limit, cut down by return: each forced cut is the
    least harmful of every split fixed to either side, on common fresh episodes
    (:func:`ibt.refine.by_return.prune_stage` with few episodes per candidate, counted in the
    search's budget). Cuts by training samples alone ruin a refined tree (a 29-leaf
    LunarLander tree at 21 leaves fell from 226 to about 0)."""
    if tree.n_leaves <= config.max_leaves:
        return tree
    from ibt.tasks.settings import RefineConfig

    cut = RefineConfig(stages=("shrink",), episodes=max(budget.left, 1), sweep_episodes=4,
                       max_leaves=config.max_leaves, n_envs=config.n_envs)
    shrunk, _ = prune_stage(tree, cut, budget, optional=False)
    return shrunk


def evolve(sources: list[DecisionTreeClassifier | TreeArrays], task: Task,
           config: EvolveConfig, seed: int = 0, *, expert: Any | None = None,
           progress: bool = True) -> Evolution:
    """Search trees of at most ``config.max_leaves`` leaves by return, from ``sources``."""
    rng = np.random.default_rng(seed)
    seeds = [s if isinstance(s, TreeArrays) else TreeArrays.from_sklearn(s) for s in sources]
    for s in seeds:
        if s.n_features != task.n_features:
            raise ValueError(f"a source tree reads {s.n_features} features, {task.name} has "
                             f"{task.n_features}")
    budget = _Budget.opened(task, seed, config, "evolve", progress)
    bar = budget.bar
    seeds = [_shrink(s.simplified(), config, budget) for s in seeds]
    record = Evolution(task.name, seed, config.as_params(), sources=seeds)
    mutator = TreeMutator(task, config, rng, expert)
    parents = list(seeds)
    hall: list[TreeArrays] = []
    generation = 0
    per_generation = (config.mu + config.lam) * config.generation_episodes
    while budget.left >= per_generation + config.pool_episodes:
        if generation % config.pool_every == 0:
            mutator.refresh(budget.visit(parents[0], config.pool_episodes))
        children = []
        for i in range(config.lam):
            parent = parents[i % len(parents)]
            child = arrays(mutator.mutate(nested(parent)), task.n_features, task.n_actions)
            if child.n_leaves <= config.max_leaves:
                children.append(child)
        contenders = parents + children
        means = budget.score_trees(contenders, budget.fresh(config.generation_episodes))
        means = means.mean(axis=1)
        order = sorted(range(len(contenders)),
                       key=lambda i: (-means[i], contenders[i].n_leaves, i))
        parents = [contenders[i] for i in order[:config.mu]]
        hall.append(parents[0])
        record.history.append({"generation": generation, "best": round(float(means[order[0]]), 2),
                               "mean": round(float(means.mean()), 2),
                               "leaves": parents[0].n_leaves})
        bar.set_postfix(best=f"{means[order[0]]:.0f}", leaves=parents[0].n_leaves)
        generation += 1
    bar.close()
    # finalists: the last parents, the seeds and the latest generations' best, held out
    pool: list[TreeArrays] = []
    for t in parents + hall[::-1] + seeds:
        if all(t.node_count != u.node_count or not np.array_equal(t.threshold, u.threshold)
               or not np.array_equal(t.action, u.action) for u in pool):
            pool.append(t)
        if len(pool) >= config.finalists:
            break
    record.finalists = pool
    _choose(record, budget, config.selection_episodes)
    record.episodes, record.steps = budget.used, budget.steps
    record.wall_seconds, record.cpu_seconds = budget.elapsed()
    record.steps_per_second = ((record.steps + budget.uncounted_steps)
                               / max(record.cpu_seconds, 1e-9))
    record.random_steps_per_second = _random_speed(task, config, seed)
    return record


def _choose(record: Evolution, budget: _Budget, selection_episodes: int) -> None:
    """Score the record's finalists on its run's first ``selection_episodes`` held-out
    selection episodes (not counted in the budget) and choose the best (fewer leaves, then
    the earlier finalist, break ties)."""
    held_out = selection_seeds(selection_episodes, record.seed, offset=EVOLVE_SELECTION_OFFSET)
    pool = record.finalists
    scores = budget.score_trees(pool, held_out, count=False).mean(axis=1)
    record.selection_means = [float(s) for s in scores]
    record.best_index = max(range(len(pool)), key=lambda i: (scores[i], -pool[i].n_leaves, -i))


class _NoProgress:
    """A progress bar that shows nothing (the choice's episodes are not the budget's)."""

    def update(self, n: int) -> None:
        pass


def reselect(record: Evolution, task: Task, selection_episodes: int) -> Evolution:
    """The same search, its finalists chosen on ``selection_episodes`` held-out episodes
    instead (the first of them the ones the search used, so a longer choice only adds
    episodes). The search's trajectory does not depend on its choice, so this is exactly the
    search run with that ``selection_episodes``, for the CPU of the choice alone, which is
    added to the record's cost. A longer choice pays where finalists are a few points apart
    and the episodes' spread is wide (LunarLander)."""
    config = EvolveConfig(**{**{k: v for k, v in record.config.items()
                                if k in EvolveConfig.__dataclass_fields__},
                             "selection_episodes": selection_episodes})
    cpu_start = time.process_time()
    chosen = replace(record, config={**record.config, "selection_episodes": selection_episodes},
                     finalists=list(record.finalists))
    budget = _Budget(task, record.seed, config, _NoProgress())
    _choose(chosen, budget, selection_episodes)
    chosen.cpu_seconds = record.cpu_seconds + time.process_time() - cpu_start
    stepped = record.steps_per_second * record.cpu_seconds + budget.uncounted_steps
    chosen.steps_per_second = stepped / max(chosen.cpu_seconds, 1e-9)
    return chosen


def _random_speed(task: Task, config: EvolveConfig, seed: int) -> float:
    """Environment steps per CPU-second of a uniform random policy, stepped by the same
    batched rollout (episode seeds of their own, not counted in the budget)."""
    rng = np.random.default_rng(seed)
    cpu = time.process_time()
    result = rollout(task, lambda obs: rng.integers(task.n_actions, size=len(obs)),
                     [EVOLVE_SEED_BASE - 1000 + i for i in range(4 * config.n_envs)],
                     n_envs=config.n_envs)
    return float(result.lengths.sum() / max(time.process_time() - cpu, 1e-9))


__all__ = ["Evolution", "EvolveConfig", "evolve", "reselect"]
