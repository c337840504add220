"""Interactive distillation of an expert into a CART decision tree.

One loop serves every method; the methods differ only in the beta schedule and the sample
weights (:data:`METHODS`):

==============  ===========================  =========================================
method          beta_i (expert probability)  fit on
==============  ===========================  =========================================
bc              1 every iteration            aggregated data, uniform weights
dagger          p**i, p = 0.5                aggregated data, uniform weights
viper           1, then 0                    resampled with p ~ max_a Q - min_a Q
imitation-bt    1 - i/N                      resampled with p ~ max_a Q - min_a Q
==============  ===========================  =========================================

Beyond the paper, ``imitation-bt+rel`` is Imitation-BT's setting with another tree fit:
:func:`ibt.distill.relational.fit_relational_tree`, whose splits may be relational tests
``w1 * x_i + w2 * x_j <= t`` where they beat every axis-aligned split by a margin.
A method's ``fit`` is its tree fit; the paper's four fit scikit-learn's CART (:func:`fit_cart`).

Each iteration rolls out the mixed policy (per step, the expert's action with probability
beta_i, else the current tree's) in whole episodes until the iteration's label budget is spent;
the expert labels every visited state; the data are aggregated; a tree is fitted; the tree is
scored on held-out episodes. The best tree (highest mean return, then fewest nodes, then
earliest) is the result. For PPO/A2C experts Q is replaced by log pi(a|s).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np
from sklearn.tree import DecisionTreeClassifier
from tqdm import tqdm

from ibt.distill import schedules
from ibt.evaluate.policies import CompiledTree
from ibt.evaluate.rollouts import TRAIN_SEED_BASE, rollout, selection_seeds
from ibt.experts.expert import Expert
from ibt.tasks.task import Task


def fit_cart(x: np.ndarray, y: np.ndarray, config: Any, seed: int) -> DecisionTreeClassifier:
    """scikit-learn's CART within the settings' size limits and cost-complexity pruning."""
    return DecisionTreeClassifier(max_leaf_nodes=config.max_leaf_nodes, max_depth=config.max_depth,
                                  ccp_alpha=config.ccp_alpha, random_state=seed).fit(x, y)


def fit_relational(x: np.ndarray, y: np.ndarray, config: Any, seed: int) -> Any:
    """:func:`ibt.distill.relational.fit_relational_tree` within the settings' size limits (it
    grows to them: no cost-complexity pruning)."""
    from ibt.distill.relational import fit_relational_tree

    return fit_relational_tree(x, y, max_leaf_nodes=config.max_leaf_nodes,
                               max_depth=config.max_depth, seed=seed)


@dataclass(frozen=True)
class Method:
    schedule: schedules.Schedule
    weighted: bool
    fit: Callable[[np.ndarray, np.ndarray, Any, int], Any] = fit_cart  # the tree fit
    prunes: bool = True  # the fit takes cost-complexity pruning (ccp_alpha)


METHODS: dict[str, Method] = {
    "bc": Method(schedules.constant(1.0), weighted=False),
    "dagger": Method(schedules.exponential(0.5), weighted=False),
    "viper": Method(schedules.first_only(), weighted=True),
    "imitation-bt": Method(schedules.linear(), weighted=True),
    "imitation-bt+rel": Method(schedules.linear(), weighted=True, fit=fit_relational,
                               prunes=False),
}


def check_loop_settings(method: str, n_iterations: int, labels_per_iteration: int) -> None:
    """The checks every interactive loop's settings pass (:class:`DistillConfig`,
    :class:`ibt.distill.continuous.BoxDistillConfig`): a known method, a positive budget."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if n_iterations < 1 or labels_per_iteration < 1:
        raise ValueError("n_iterations and labels_per_iteration must be positive")


@dataclass(frozen=True)
class DistillConfig:
    """Everything that determines a distillation run (with the expert and the seed)."""

    method: str = "imitation-bt"
    n_iterations: int = 50
    labels_per_iteration: int = 1000
    selection_episodes: int = 20
    max_leaf_nodes: int | None = None
    max_depth: int | None = None
    ccp_alpha: float = 0.0
    schedule: schedules.Schedule | None = None  # overrides the method's schedule
    collect_envs: int = 2
    eval_envs: int = 20

    def __post_init__(self) -> None:
        check_loop_settings(self.method, self.n_iterations, self.labels_per_iteration)

    @property
    def beta(self) -> schedules.Schedule:
        return self.schedule or METHODS[self.method].schedule

    @property
    def weighted(self) -> bool:
        return METHODS[self.method].weighted

    def as_params(self) -> dict[str, Any]:
        out = asdict(self)
        out["schedule"] = asdict(self.beta)
        return out

    @classmethod
    def for_task(cls, task: Task, **overrides: Any) -> DistillConfig:
        """The task's budget and size limits (its catalogue entry), with ``overrides`` on top."""
        b = task.budget
        base = {"max_leaf_nodes": b.max_leaf_nodes, "max_depth": b.max_depth,
                "ccp_alpha": b.ccp_alpha, "labels_per_iteration": b.labels_per_iteration}
        return cls(**{**base, **overrides})


@dataclass
class Distillation:
    """A run's record: every iteration's tree and scores, and the chosen best tree."""

    task: str
    expert: str
    seed: int
    config: dict[str, Any]
    iterations: list[dict[str, Any]] = field(default_factory=list)
    trees: list[DecisionTreeClassifier] = field(default_factory=list)
    best_index: int = -1
    wall_seconds: float = 0.0

    @property
    def best_tree(self) -> DecisionTreeClassifier:
        return self.trees[self.best_index]

    @property
    def expert_labels(self) -> int:
        return int(sum(it["labels"] for it in self.iterations))


def mix(expert_actions: np.ndarray, learner_actions: np.ndarray, beta: float,
        rng: np.random.Generator) -> np.ndarray:
    """The mixed policy's actions: per step, the expert's with probability ``beta``."""
    use_expert = rng.random(len(expert_actions)) < beta
    return np.where(use_expert, expert_actions, learner_actions)


def tree_signature(tree: DecisionTreeClassifier) -> bytes:
    """A fitted tree's decision function as bytes: equal bytes, equal decisions.

    The splits (features, thresholds, children), each node's predicted class index and
    ``classes_`` (so labels {0, 1} and {0, 2} differ), behind a header of the sizes. Leaf
    sample counts are left out. Keys the scores within a run and, hashed, the cache entries
    computed from a tree.
    """
    t = tree.tree_
    classes = np.asarray(tree.classes_)
    head = np.array([t.node_count, len(classes), tree.n_features_in_], dtype=np.int64)
    parts = [head, t.feature, t.threshold, t.children_left, t.children_right,
             np.argmax(t.value[:, 0, :], axis=1)]
    out = (b"".join(np.ascontiguousarray(p).tobytes() for p in parts)
           + repr(classes.tolist()).encode())
    feature_map = getattr(tree, "feature_map_", None)  # a relational tree: its derived columns
    if feature_map is not None:
        out += b"\0relational\0" + repr(feature_map.to_json()).encode()
    return out


_signature = tree_signature  # the former private name (kept for existing callers)


class Learner(Protocol):
    """What the interactive loop fits each iteration, and how that tree acts: the one variation
    point between classification trees (CART, relational) and regression trees (Box tasks,
    :mod:`ibt.distill.continuous`)."""

    def label(self, expert: Expert, obs: np.ndarray, weighted: bool
              ) -> tuple[np.ndarray, np.ndarray]:
        """The expert's actions on a batch and each state's weight."""
        ...

    def fit(self, x: np.ndarray, y: np.ndarray) -> Any:
        """A tree fitted on the (resampled) aggregate."""
        ...

    def signature(self, tree: Any) -> bytes:
        """The tree's decision function as bytes (equal bytes, equal actions)."""
        ...

    def predictor(self, tree: Any) -> Callable[[np.ndarray], np.ndarray]:
        """The tree's actions on a batch of feature rows."""
        ...

    def mix(self, expert_actions: np.ndarray, tree_actions: np.ndarray, beta: float,
            rng: np.random.Generator) -> np.ndarray:
        """Per row, the expert's action with probability ``beta``, else the tree's."""
        ...


class MethodSchedule:
    """Settings whose ``method`` names an entry of :data:`METHODS`: its beta schedule (the
    expert's probability per iteration) and whether labels are weighted."""

    method: str

    @property
    def beta(self) -> Any:
        return METHODS[self.method].schedule

    @property
    def weighted(self) -> bool:
        return METHODS[self.method].weighted


class CommandVectors:
    """How a learner of ``Box`` actions labels and mixes (the regression and controller
    learners): the expert's command vectors (weighted by its critic where the method weighs,
    else one pass of ``act``), and per row the expert's whole vector or the tree's."""

    def label(self, expert: Expert, obs: np.ndarray, weighted: bool
              ) -> tuple[np.ndarray, np.ndarray]:
        if weighted:
            return expert.label(obs)
        return expert.act(obs), np.ones(len(obs))  # the weights are not used: one pass

    def mix(self, expert_actions: np.ndarray, tree_actions: np.ndarray, beta: float,
            rng: np.random.Generator) -> np.ndarray:
        use_expert = mix(np.arange(len(expert_actions)), np.full(len(expert_actions), -1),
                         beta, rng) >= 0
        return np.where(use_expert[:, None], expert_actions, tree_actions)


@dataclass(frozen=True)
class ClassifierLearner:
    """A classification tree: scikit-learn's CART, or the relational learner of
    :mod:`ibt.distill.relational` (splits may test ``w1 * x_i + w2 * x_j``)."""

    config: DistillConfig
    seed: int

    def label(self, expert: Expert, obs: np.ndarray, weighted: bool
              ) -> tuple[np.ndarray, np.ndarray]:
        return expert.label(obs)  # one forward pass gives the weights too

    def fit(self, x: np.ndarray, y: np.ndarray) -> Any:
        return METHODS[self.config.method].fit(x, y, self.config, self.seed)

    def signature(self, tree: Any) -> bytes:
        return tree_signature(tree)

    def predictor(self, tree: Any) -> Callable[[np.ndarray], np.ndarray]:
        return CompiledTree(tree).predict  # a relational tree's derived columns included

    def mix(self, expert_actions: np.ndarray, tree_actions: np.ndarray, beta: float,
            rng: np.random.Generator) -> np.ndarray:
        return mix(expert_actions, tree_actions, beta, rng)


def distill(task: Task, expert: Expert, config: DistillConfig, seed: int = 0, *,
            progress: bool = True) -> Distillation:
    """Run the interactive loop; see the module docstring."""
    if expert.n_actions != task.n_actions:
        raise ValueError(f"the expert has {expert.n_actions} actions, {task.name} has "
                         f"{task.n_actions}")
    if not METHODS[config.method].prunes and config.ccp_alpha:
        raise ValueError(f"{config.method}'s tree fit grows to max_leaf_nodes/max_depth; it "
                         "has no cost-complexity pruning (ccp_alpha must be 0)")
    return interactive_loop(task, expert, config, seed, ClassifierLearner(config, seed),
                            progress=progress)


def interactive_loop(task: Task, expert: Expert, config: Any, seed: int, learner: Learner, *,
                     progress: bool = True) -> Distillation:
    """The loop itself, for any :class:`Learner`: per iteration, roll out the mixed policy
    until the label budget is spent, aggregate the expert's labels, resample by weight where
    the method weighs, fit, and score the tree on the held-out selection episodes; the best
    tree wins. ``config`` gives ``method``, ``beta``, ``weighted``, the budgets and envs."""
    rng = np.random.default_rng(seed)
    n = config.n_iterations
    record = Distillation(task.name, expert.algo, seed, config.as_params())
    features: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    weights: list[np.ndarray] = []
    scored: dict[bytes, tuple[float, float]] = {}
    eval_seeds = selection_seeds(config.selection_episodes, seed)
    predict: Callable[[np.ndarray], np.ndarray] | None = None
    start = time.perf_counter()
    bar = tqdm(range(n), desc=f"{config.method} {task.name}/{expert.algo} s{seed}",
               disable=not progress, leave=False, unit="it")
    shown = LoopProgress(bar)
    n_labels = 0
    for i in bar:
        beta = config.beta(i, n)

        def act(obs: np.ndarray, beta: float = beta,
                predict: Callable[[np.ndarray], np.ndarray] | None = predict) -> np.ndarray:
            expert_actions, weight = learner.label(expert, obs, config.weighted)
            features.append(task.features(obs))
            labels.append(expert_actions)
            weights.append(weight)
            shown.labelled(len(obs))
            if predict is None or beta >= 1.0:
                return expert_actions
            return learner.mix(expert_actions, predict(features[-1]), beta, rng)

        shown.phase("collecting")
        rollout(task, act, iteration_seeds(seed, i), n_envs=config.collect_envs,
                budget=config.labels_per_iteration)
        x = np.concatenate(features)
        y = np.concatenate(labels)
        new_labels, n_labels = len(y) - n_labels, len(y)
        if config.weighted:
            x, y = resample(x, y, weights, rng)
        shown.phase("fitting")
        tree = learner.fit(x, y)
        predict = learner.predictor(tree)
        shown.phase("scoring")
        record_iteration(record, scored, tree, learner.signature(tree), i, beta, new_labels,
                         n_labels, task, _on_observations(task, predict), eval_seeds,
                         config.eval_envs)
        shown.best = max(s for s, _ in scored.values())
    bar.close()
    return choose_best(record, start)


class LoopProgress:
    """What the loop's bar shows beside its iterations: the expert labels collected so far,
    what the iteration is doing and the best tree's selection mean. The bar is redrawn as the
    labels come in (at most every :attr:`interval` seconds), so a long iteration does not look
    stalled; a disabled bar shows and costs nothing."""

    interval = 0.5  #: seconds between redraws while labels come in

    def __init__(self, bar: Any) -> None:
        self.bar, self.labels, self.doing = bar, 0, ""
        self.best: float | None = None
        self.drawn = time.monotonic()

    def text(self) -> str:
        best = "" if self.best is None else f", best {self.best:.2f}"
        return f"{self.labels:,} labels{best}; {self.doing}"

    def phase(self, doing: str) -> None:
        """The iteration's phase (``collecting``, ``fitting``, ``scoring``), shown now."""
        if self.bar.disable:
            return
        self.doing = doing
        self.bar.set_postfix_str(self.text())
        self.drawn = time.monotonic()

    def labelled(self, count: int) -> None:
        """``count`` new expert labels; redraws the bar when :attr:`interval` has passed."""
        if self.bar.disable:
            return
        self.labels += count
        if time.monotonic() - self.drawn >= self.interval:
            self.bar.set_postfix_str(self.text())
            self.drawn = time.monotonic()


def _on_observations(task: Task, predict: Callable[[np.ndarray], np.ndarray]) -> Any:
    """``act`` of a tree's predictor on raw observations."""
    return lambda obs: predict(task.features(obs))


def iteration_seeds(seed: int, iteration: int) -> list[int]:
    """The episode seeds iteration ``iteration`` of run ``seed`` collects on (its own block of
    1,000 in the run's block of training seeds)."""
    return [TRAIN_SEED_BASE + 100_000 * seed + 1_000 * iteration + k for k in range(1_000)]


def resample(x: np.ndarray, y: np.ndarray, weights: list[np.ndarray],
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The aggregated data drawn again with replacement, as many rows, each with probability
    proportional to its state's weight (uniform where every weight is 0)."""
    w = np.concatenate(weights)
    p = w / w.sum() if w.sum() > 0 else None
    idx = rng.choice(len(x), size=len(x), replace=True, p=p)
    return x[idx], y[idx]


def record_iteration(record: Distillation, scored: dict[bytes, tuple[float, float]], tree: Any,
                     key: bytes, iteration: int, beta: float, new_labels: int, dataset: int,
                     task: Task, policy: Any, eval_seeds: list[int], eval_envs: int) -> None:
    """Append one iteration's tree and row; ``policy`` (the tree's ``act``) is rolled out on
    ``eval_seeds`` only for a tree not scored before (``key``: its signature), so equal trees
    share one score."""
    if key not in scored:
        result = rollout(task, policy, eval_seeds, n_envs=eval_envs)
        scored[key] = (result.mean, result.std)
    mean, std = scored[key]
    record.trees.append(tree)
    record.iterations.append({
        "iteration": iteration, "beta": beta, "labels": new_labels, "dataset": dataset,
        "nodes": int(tree.tree_.node_count), "leaves": int(tree.get_n_leaves()),
        "selection_mean": mean, "selection_std": std,
    })


def choose_best(record: Distillation, start: float) -> Distillation:
    """The run's best iteration (highest selection mean, then fewest nodes, then earliest)
    and its wall time since ``start`` (a ``perf_counter`` reading)."""
    record.best_index = max(
        range(len(record.iterations)), key=lambda k: (record.iterations[k]["selection_mean"],
                                                      -record.iterations[k]["nodes"], -k))
    record.wall_seconds = time.perf_counter() - start
    return record


def learner_policy(task: Task, compiled: CompiledTree):
    """``act`` of a compiled tree on raw observations."""
    return lambda obs: compiled.predict(task.features(obs))
