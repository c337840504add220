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
* **mutations**: move one threshold (in units of its feature's spread over visited states),
  move all thresholds a little, change a split's feature (a new threshold drawn from visited
  states), change a leaf's action, replace a subtree by a leaf, grow a leaf into a split.
* **the expert's help** (optional): a pool of states the current best tree visits is labelled
  by the expert (DAgger's labels, on the small tree's own state distribution); "grow" then
  fits the split that best separates the expert's labels among the pool states reaching the
  leaf (a CART stump), and "relabel" gives a leaf the expert's majority action there.
* the run's final parents and the best of each generation are compared on held-out selection
  episodes (disjoint from the refinement episodes and from the final evaluation), and the best
  is returned.

Deterministic in the seed; the budget is counted in episodes. Trees of different shapes run
side by side in one batch of environments (:class:`Forest`), the trees decided on the batch.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.distill.relational import AugmentedTask
from ibt.evaluate.rollouts import REFINE_SEED_BASE, rollout, selection_seeds
from ibt.refine.by_return import _Episodes, _prune_stage
from ibt.refine.tree_arrays import TreeArrays, _from_nested
from ibt.tasks.settings import EvolveConfig
from ibt.tasks.task import Task

#: Held-out selection episodes of the structure search (the run's block of 10,000 seeds:
#: refinement's own choice uses 5,000 and up, the distillation's below)
EVOLVE_SELECTION_OFFSET = 7_000
EVOLVE_SEED_BASE = REFINE_SEED_BASE + 500_000  # its refinement episodes: apart from by_return's
MUTATIONS = ("threshold", "thresholds", "feature", "action", "prune", "grow", "relabel")


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


class Forest:
    """Trees of different shapes decided side by side: ``decide(x, members)`` routes row ``i``
    through tree ``members[i]`` (float32 features widened to float64, as scikit-learn).

    A rollout reads only the columns some split tests (:meth:`reader`: on a relational search's
    hundred-odd candidate columns, computing them all on every step cost more than the trees),
    and walks all trees at once on flat arrays; a leaf points to itself, so rows that reach a
    leaf early stay there."""

    def __init__(self, trees: list[TreeArrays]) -> None:
        self.trees = trees
        width = max(t.node_count for t in trees)
        self.width = width
        tested = sorted({int(f) for t in trees for f in t.feature[~t.is_leaf]})
        self.columns = np.array(tested or [0], dtype=np.int64)  # the features some split reads
        position = {c: k for k, c in enumerate(self.columns.tolist())}
        size = len(trees) * width
        self.feature = np.zeros(size, dtype=np.int64)  # position in ``columns``
        self.threshold = np.zeros(size, dtype=np.float64)
        self.left = np.arange(size, dtype=np.int64)  # flat node numbers; a leaf: itself
        self.right = np.arange(size, dtype=np.int64)
        self.action = np.zeros(size, dtype=np.int64)
        for i, t in enumerate(trees):
            base, split = i * width, ~t.is_leaf
            nodes = base + np.flatnonzero(split)
            self.feature[nodes] = [position[int(f)] for f in t.feature[split]]
            self.threshold[nodes] = t.threshold[split]
            self.left[nodes] = base + t.left[split]
            self.right[nodes] = base + t.right[split]
            self.action[base:base + t.node_count] = t.action
        self.depth = max(t.depth() for t in trees)
        self._lists: tuple[list, ...] | None = None

    def __len__(self) -> int:
        return len(self.trees)

    def decide(self, features: np.ndarray, members: np.ndarray) -> np.ndarray:
        x = np.asarray(features, dtype=np.float32).astype(np.float64)
        return self.decide_columns(x[:, self.columns], members)

    def decide_columns(self, x: np.ndarray, members: np.ndarray) -> np.ndarray:
        """:meth:`decide` on rows of :attr:`columns` only, already widened to float64
        (:meth:`reader`'s rows)."""
        if len(x) <= SMALL_BATCH:
            return self._decide_rows(x, members)
        n, n_columns = x.shape
        flat = x.ravel()
        row_start = np.arange(n, dtype=np.int64) * n_columns
        node = np.asarray(members, dtype=np.int64) * self.width
        for _ in range(self.depth):
            go_left = flat[row_start + self.feature[node]] <= self.threshold[node]
            node = np.where(go_left, self.left[node], self.right[node])
        return self.action[node]

    def _decide_rows(self, x: np.ndarray, members: np.ndarray) -> np.ndarray:
        """A rollout's last few rows: walking in Python beats array passes (the same float64
        comparisons)."""
        if self._lists is None:
            self._lists = (self.feature.tolist(), self.threshold.tolist(), self.left.tolist(),
                           self.right.tolist(), self.action.tolist())
        feature, threshold, left, right, action = self._lists
        width = self.width
        out = []
        for row, member in zip(x.tolist(), np.asarray(members).tolist(), strict=True):
            node = member * width
            while left[node] != node:
                node = left[node] if row[feature[node]] <= threshold[node] else right[node]
            out.append(action[node])
        return np.array(out, dtype=np.int64)

    def reader(self, task: Task) -> Callable[[np.ndarray], np.ndarray]:
        """Raw observations -> the :attr:`columns` of ``task.features``, widened as
        :meth:`decide` widens them; a relational search's derived columns are computed by
        :meth:`ibt.bt.linear.FeatureMap.augment`'s rule (double products and sum, then the
        float32 value) for the tested ones only."""
        columns = self.columns
        fmap = getattr(task, "feature_map", None)
        if not isinstance(task, AugmentedTask) or fmap is None:
            def read(obs: np.ndarray) -> np.ndarray:
                return task.features(obs).astype(np.float64)[:, columns]
            return read
        n = fmap.n_features
        observed = np.flatnonzero(columns < n)
        derived = np.flatnonzero(columns >= n)
        forms = [fmap.form(int(c)) for c in columns[derived]]
        first = np.array([f.i for f in forms], dtype=np.int64)
        second = np.array([f.j for f in forms], dtype=np.int64)
        w1 = np.array([f.w1 for f in forms], dtype=np.float64)
        w2 = np.array([f.w2 for f in forms], dtype=np.float64)
        observed_columns = columns[observed]

        def read_augmented(obs: np.ndarray) -> np.ndarray:
            x = Task.features(task, obs).astype(np.float64)
            out = np.empty((len(x), len(columns)), dtype=np.float64)
            out[:, observed] = x[:, observed_columns]
            if len(forms):
                values = w1 * x[:, first] + w2 * x[:, second]
                with np.errstate(over="ignore"):
                    out[:, derived] = values.astype(np.float32)
            return out
        return read_augmented


#: batches up to this many rows are decided row by row (see :meth:`Forest._decide_rows`)
SMALL_BATCH = 16


class _Budget(_Episodes):
    """Fresh refinement episodes of the search (its own seed block), counted; trees of any
    shapes are scored side by side as a :class:`Forest`."""

    def __init__(self, task: Task, seed: int, config: EvolveConfig, bar: Any) -> None:
        super().__init__(task, seed, config, bar)  # type: ignore[arg-type]
        self.next_seed = EVOLVE_SEED_BASE + 1_000_000 * seed
        self.uncounted_steps = 0  # stepped outside the budget (the held-out choice)

    def score_trees(self, trees: list[TreeArrays], seeds: list[int], *, count: bool = True
                    ) -> np.ndarray:
        """``(trees, episodes)`` returns, every tree on every seed (as
        :meth:`ibt.refine.by_return._Episodes.score`, reading only the tested columns)."""
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


# --- trees as nested tuples: ("leaf", action) or ("split", feature, threshold, left, right) ---

def nested(tree: TreeArrays, node: int = 0) -> tuple:
    if tree.is_leaf[node]:
        return ("leaf", int(tree.action[node]))
    return ("split", int(tree.feature[node]), float(tree.threshold[node]),
            nested(tree, int(tree.left[node])), nested(tree, int(tree.right[node])))


def arrays(node: tuple, n_features: int, n_actions: int) -> TreeArrays:
    def weighted(n: tuple) -> tuple:
        if n[0] == "leaf":
            return ("leaf", n[1], 1.0)
        return ("split", n[1], n[2], weighted(n[3]), weighted(n[4]), 1.0)

    return _from_nested(weighted(node), n_features, n_actions).simplified()


def _paths(node: tuple, path: tuple = ()) -> list[tuple[tuple, tuple]]:
    """Every (path, subtree); a path is a tuple of 3 (left) / 4 (right) child positions."""
    out = [(path, node)]
    if node[0] == "split":
        out += _paths(node[3], (*path, 3)) + _paths(node[4], (*path, 4))
    return out


def _replace(node: tuple, path: tuple, new: tuple) -> tuple:
    if not path:
        return new
    head, rest = path[0], path[1:]
    parts = list(node)
    parts[head] = _replace(node[head], rest, new)
    return tuple(parts)


def _leaves(node: tuple) -> int:
    return 1 if node[0] == "leaf" else _leaves(node[3]) + _leaves(node[4])


class _Mutator:
    """One random mutation of a tree, with the visited-state pool and the expert's labels."""

    def __init__(self, task: Task, config: EvolveConfig, rng: np.random.Generator,
                 expert: Any | None) -> None:
        self.task, self.config, self.rng, self.expert = task, config, rng, expert
        self.pool = np.zeros((0, task.n_features), dtype=np.float32)
        self.labels = np.zeros(0, dtype=np.int64)
        self.scores = np.zeros((0, task.n_actions))  # the expert's, where leaf_rule is "score"
        self.spread = np.ones(task.n_features)

    def refresh(self, states: np.ndarray) -> None:
        keep = self.rng.permutation(len(states))[:4000]
        self.pool = states[keep]
        box = np.asarray(self.task.high, float) - np.asarray(self.task.low, float)
        floor = np.where(np.isfinite(box) & (box > 0), 1e-3 * box, 1e-3)
        self.spread = np.maximum(self.pool.astype(np.float64).std(axis=0), floor)
        if self.expert is not None and self.config.use_expert:
            observed = self.task.observations(self.pool)
            if self.config.leaf_rule == "score":
                self.scores = np.asarray(self.expert.scores(observed), dtype=np.float64)
                self.labels = np.argmax(self.scores, axis=1).astype(np.int64)
            else:
                self.labels = np.asarray(self.expert.act(observed), dtype=np.int64)

    def _leaf_action(self, mask: np.ndarray) -> int:
        """The expert's action for the pool states in ``mask`` (at least one): the majority of
        its labels ("vote") or the highest mean score ("score": the best single action for
        the region by the expert's own values)."""
        if self.config.leaf_rule == "score":
            return int(np.argmax(self.scores[mask].mean(axis=0)))
        return int(np.argmax(np.bincount(self.labels[mask], minlength=self.task.n_actions)))

    def _reaching(self, root: tuple, path: tuple) -> np.ndarray:
        mask = np.ones(len(self.pool), dtype=bool)
        node = root
        for step in path:
            go_left = self.pool[:, node[1]].astype(np.float64) <= node[2]
            mask &= go_left if step == 3 else ~go_left
            node = node[step]
        return mask

    def _threshold_from_pool(self, feature: int, mask: np.ndarray | None = None) -> float:
        values = self.pool[mask if mask is not None and mask.any() else slice(None), feature]
        if len(values) == 0:
            lo, hi = self.task.low[feature], self.task.high[feature]
            return float(self.rng.uniform(lo, hi))
        return float(values[self.rng.integers(len(values))])

    def _stump(self, root: tuple, path: tuple, leaf: tuple) -> tuple | None:
        """The split that best separates the expert's labels among the pool states reaching
        the leaf (CART's Gini), with the majority label on each side."""
        mask = self._reaching(root, path)
        if mask.sum() < 10 or len(self.labels) != len(self.pool):
            return None
        stump = DecisionTreeClassifier(max_depth=1, random_state=0)
        weight = None
        if self.config.leaf_rule == "score":
            scores = self.scores[mask]
            weight = scores.max(axis=1) - scores.min(axis=1) + 1e-12
        stump.fit(self.pool[mask], self.labels[mask], sample_weight=weight)
        t = stump.tree_
        if t.node_count < 3:
            return None
        feature, threshold = int(t.feature[0]), float(t.threshold[0])
        if self.config.leaf_rule == "score":
            go_left = self.pool[:, feature].astype(np.float64) <= threshold
            left = ("leaf", self._leaf_action(mask & go_left))
            right = ("leaf", self._leaf_action(mask & ~go_left))
        else:
            classes = stump.classes_
            left = ("leaf", int(classes[int(np.argmax(t.value[1, 0]))]))
            right = ("leaf", int(classes[int(np.argmax(t.value[2, 0]))]))
        if left[1] == right[1]:
            return None
        return ("split", feature, threshold, left, right)

    def mutate(self, root: tuple) -> tuple:
        kind = MUTATIONS[int(self.rng.integers(len(MUTATIONS)))]
        if kind == "relabel" and (self.expert is None or not self.config.use_expert):
            kind = "action"
        nodes = _paths(root)
        splits = [(p, n) for p, n in nodes if n[0] == "split"]
        leaves = [(p, n) for p, n in nodes if n[0] == "leaf"]
        n_actions = self.task.n_actions
        if kind in ("threshold", "feature", "thresholds", "prune") and not splits:
            kind = "grow"
        if kind == "threshold":
            path, node = splits[int(self.rng.integers(len(splits)))]
            step = self.rng.normal(0, self.config.sigma) * self.spread[node[1]]
            return _replace(root, path, ("split", node[1], node[2] + step, node[3], node[4]))
        if kind == "thresholds":
            out = root
            for path, node in splits:
                current = dict(_paths(out))[path]
                step = self.rng.normal(0, self.config.sigma / 4) * self.spread[node[1]]
                out = _replace(out, path, ("split", current[1], current[2] + step,
                                           current[3], current[4]))
            return out
        if kind == "feature":
            path, node = splits[int(self.rng.integers(len(splits)))]
            feature = int(self.rng.integers(self.task.n_features))
            threshold = self._threshold_from_pool(feature, self._reaching(root, path))
            return _replace(root, path, ("split", feature, threshold, node[3], node[4]))
        if kind == "action":
            path, node = leaves[int(self.rng.integers(len(leaves)))]
            action = int(self.rng.integers(n_actions - 1))
            action += action >= node[1]
            return _replace(root, path, ("leaf", action))
        if kind == "prune":
            path, node = splits[int(self.rng.integers(len(splits)))]
            keep = node[3] if self.rng.random() < 0.5 else node[4]
            return _replace(root, path, keep)
        if kind == "relabel":
            path, node = leaves[int(self.rng.integers(len(leaves)))]
            mask = self._reaching(root, path)
            if not mask.any():
                return self.mutate(root)
            return _replace(root, path, ("leaf", self._leaf_action(mask)))
        # grow
        if _leaves(root) >= self.config.max_leaves:
            return self._grow_or_prune(root)
        return self._grow(root, leaves)

    def _grow(self, root: tuple, leaves: list[tuple[tuple, tuple]]) -> tuple:
        path, node = leaves[int(self.rng.integers(len(leaves)))]
        if self.expert is not None and self.config.use_expert and self.rng.random() < 0.7:
            stump = self._stump(root, path, node)
            if stump is not None:
                return _replace(root, path, stump)
        feature = int(self.rng.integers(self.task.n_features))
        threshold = self._threshold_from_pool(feature, self._reaching(root, path))
        other = int(self.rng.integers(self.task.n_actions))
        children = (node, ("leaf", other)) if self.rng.random() < 0.5 else (("leaf", other), node)
        return _replace(root, path, ("split", feature, threshold, *children))

    def _grow_or_prune(self, root: tuple) -> tuple:
        """At the leaf limit, growth must pay for itself: cut a random subtree, then grow."""
        splits = [(p, n) for p, n in _paths(root) if n[0] == "split"]
        path, node = splits[int(self.rng.integers(len(splits)))]
        cut = _replace(root, path, node[3] if self.rng.random() < 0.5 else node[4])
        leaves = [(p, n) for p, n in _paths(cut) if n[0] == "leaf"]
        return self._grow(cut, leaves)


def _shrink(tree: TreeArrays, config: EvolveConfig, budget: _Budget) -> TreeArrays:
    """A seed tree larger than the leaf limit, cut down by return: each forced cut is the
    least harmful of every split fixed to either side, on common fresh episodes
    (:func:`ibt.refine.by_return._prune_stage` with few episodes per candidate, counted in the
    search's budget). Cuts by training samples alone ruin a refined tree (a 29-leaf
    LunarLander tree at 21 leaves fell from 226 to about 0)."""
    if tree.n_leaves <= config.max_leaves:
        return tree
    from ibt.tasks.settings import RefineConfig

    cut = RefineConfig(stages=("shrink",), episodes=max(budget.left, 1), sweep_episodes=4,
                       max_leaves=config.max_leaves, n_envs=config.n_envs)
    shrunk, _ = _prune_stage(tree, cut, budget, optional=False)
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
    mutator = _Mutator(task, config, rng, expert)
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


__all__ = ["Evolution", "EvolveConfig", "Forest", "evolve", "reselect"]
