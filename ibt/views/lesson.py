"""The method laid open, stage by stage: what ``notebooks/08_lesson.ipynb`` computes.

Each function returns plain data (tables, trees, BTs) for one stage of the lesson; the views
(figures, widgets, the static fallback) live in :mod:`ibt.views.widgets`.

* :func:`open_iteration`: one iteration of the interactive loop of :mod:`ibt.distill.loop`, replayed
  from iteration 0 with the run's own seed so that its random draws (who acts, which samples are
  resampled) are the run's: the mixed rollout, the expert's labels, the Q-gap weights, the
  resampled data and the fitted tree, which must equal the cached run's tree of that iteration
  (``matches_run``; a test replays a fresh run iteration by iteration);
* :func:`ibt.views.lesson_synthesis.synthesis_stages`: the synthesis chain (tree, paths, DNF per
  action, Espresso, threshold merge, ordering and default, BT) with the rule, literal and node
  counts at each stage;
* :func:`visited_states`: the states a policy visits when it drives (distribution shift);
* :func:`schedule_view`: one (beta schedule, leaf limit) setting of the distillation with its
  tree, BT, node counts and retention, all through the cached functions;
* :mod:`ibt.views.lesson_edits`: editing a synthesised BT by hand (``guard``, ``add_guard``,
  ``decision_diff``);
* the exercises' answers (:func:`answer_iteration`, :func:`answer_defaults`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import BehaviorTree
from ibt.distill import schedules
from ibt.distill.loop import DistillConfig
from ibt.evaluate.policies import CompiledTree
from ibt.evaluate.rollouts import TRAIN_SEED_BASE, retention_norm, rollout
from ibt.experts.expert import Expert, load_expert
from ibt.profiles import Config
from ibt.runs.steps import distill_cached
from ibt.tasks.catalogue import Task, get_task


# ------------------------------------------------------------------ 1. one iteration, laid open
@dataclass(frozen=True)
class OpenIteration:
    """One iteration of a distillation run with everything the loop saw and made."""

    task: Task
    expert: str
    seed: int
    iteration: int
    n_iterations: int
    beta: float
    weighted: bool
    steps: pd.DataFrame  # this iteration's rollout: features, expert/tree action, actor, weight
    data: pd.DataFrame  # the aggregated data of iterations 0..i with weights and draw counts
    tree: DecisionTreeClassifier  # fitted on the resampled data
    run_tree: DecisionTreeClassifier  # the cached run's tree of the same iteration

    @property
    def matches_run(self) -> bool:
        """Does the replayed tree equal the run's (splits, thresholds, leaf actions, classes)?"""
        return same_tree(self.tree, self.run_tree)

    def summary(self) -> pd.Series:
        """The iteration in numbers."""
        steps = self.steps
        by_tree = steps[steps.actor == "tree"]
        facts = {
            "iteration": self.iteration, "beta (expert share)": round(self.beta, 3),
            "steps rolled out": len(steps),
            "steps the expert drove": int((steps.actor == "expert").sum()),
            "steps the tree drove": len(by_tree),
            "tree's action != expert's label (all steps)": int(
                (steps.tree_action.notna() & (steps.tree_action != steps.expert_action)).sum()),
            "aggregated labels (iterations 0..i)": len(self.data),
            "distinct samples drawn by resampling": int((self.data.draws > 0).sum()),
            "fitted tree: nodes / leaves": f"{self.tree.tree_.node_count} / "
                                           f"{self.tree.get_n_leaves()}",
            "equals the cached run's tree of this iteration": self.matches_run,
        }
        return pd.Series(facts, name=f"{self.task.name} / {self.expert}, seed {self.seed}")


def same_tree(a: DecisionTreeClassifier, b: DecisionTreeClassifier) -> bool:
    """Equal decision functions by structure: splits, thresholds, leaf actions and classes."""
    ta, tb = a.tree_, b.tree_
    if ta.node_count != tb.node_count or list(a.classes_) != list(b.classes_):
        return False
    return all(np.array_equal(x, y) for x, y in [
        (ta.feature, tb.feature), (ta.threshold, tb.threshold),
        (ta.children_left, tb.children_left), (ta.children_right, tb.children_right),
        (np.argmax(ta.value[:, 0, :], axis=1), np.argmax(tb.value[:, 0, :], axis=1))])


def _run_config(run_config: dict[str, Any]) -> DistillConfig:
    return DistillConfig(**{**run_config, "schedule": schedules.Schedule(**run_config["schedule"])})


def replay_iterations(task: Task, expert: Expert, config: DistillConfig, seed: int,
                      last: int, on_iteration: Callable[[int, dict[str, Any]], None]
                      ) -> DecisionTreeClassifier:
    """The data side of :func:`ibt.distill.loop.distill` for iterations ``0..last``, step by step.

    The same rollout seeds, the same generator (seeded with ``seed``) drawn in the same order
    (who acts at each step, then the resampling), the same tree settings; held-out scoring is
    skipped (it draws nothing). ``on_iteration(i, record)`` sees each iteration's arrays.
    Returns the tree of iteration ``last``.
    """
    rng = np.random.default_rng(seed)
    n = config.n_iterations
    features: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    weights: list[np.ndarray] = []
    learner: CompiledTree | None = None
    tree: DecisionTreeClassifier | None = None
    for i in range(last + 1):
        beta = config.beta(i, n)
        steps: dict[str, list[np.ndarray]] = {"x": [], "expert": [], "tree": [], "actor": [],
                                              "weight": []}

        def act(obs: np.ndarray, beta: float = beta, learner: CompiledTree | None = learner,
                steps: dict[str, list[np.ndarray]] = steps) -> np.ndarray:
            expert_actions, weight = expert.label(obs)
            x = task.features(obs)
            features.append(x)
            labels.append(expert_actions)
            weights.append(weight)
            steps["x"].append(x)
            steps["expert"].append(expert_actions)
            steps["weight"].append(weight)
            if learner is None:
                steps["tree"].append(np.full(len(x), -1))
                steps["actor"].append(np.ones(len(x), dtype=bool))
                return expert_actions
            tree_actions = learner.predict(x)  # draws nothing
            steps["tree"].append(tree_actions)
            if beta >= 1.0:  # the loop draws nothing here either
                steps["actor"].append(np.ones(len(x), dtype=bool))
                return expert_actions
            use_expert = rng.random(len(x)) < beta  # what ibt.distill.loop.mix draws
            steps["actor"].append(use_expert)
            return np.where(use_expert, expert_actions, tree_actions)

        train_seeds = [TRAIN_SEED_BASE + 100_000 * seed + 1_000 * i + k for k in range(1_000)]
        rollout(task, act, train_seeds, n_envs=config.collect_envs,
                budget=config.labels_per_iteration)
        x, y, w = np.concatenate(features), np.concatenate(labels), np.concatenate(weights)
        idx = np.arange(len(x))
        if config.weighted:
            p = w / w.sum() if w.sum() > 0 else None
            idx = rng.choice(len(x), size=len(x), replace=True, p=p)
        tree = DecisionTreeClassifier(max_leaf_nodes=config.max_leaf_nodes,
                                      max_depth=config.max_depth, ccp_alpha=config.ccp_alpha,
                                      random_state=seed)
        tree.fit(x[idx], y[idx])
        learner = CompiledTree(tree)
        on_iteration(i, {"beta": beta, "data_x": x, "data_y": y, "data_w": w, "idx": idx,
                         **{f"step_{k}": np.concatenate(v) for k, v in steps.items()}})
    assert tree is not None
    return tree


def open_iteration(cfg: Config, task: str, algo: str, iteration: int, seed: int = 0,
                   method: str = "imitation-bt") -> OpenIteration:
    """Iteration ``iteration`` of the cached ``method`` run, replayed and laid open.

    ``iteration`` is clipped to the run's last iteration (the smoke profile runs 4).
    """
    spec = get_task(task)
    run = distill_cached(cfg, spec.name, algo, method, seed)
    config = _run_config(run.config)
    iteration = max(0, min(int(iteration), len(run.trees) - 1))
    seen: dict[str, Any] = {}
    tree = replay_iterations(spec, load_expert(spec, algo), config, seed, iteration,
                             lambda i, record: seen.update(record) if i == iteration else None)
    names = list(spec.feature_names)
    tree_actions = seen["step_tree"]
    steps = pd.DataFrame(seen["step_x"], columns=names)
    steps["expert_action"] = seen["step_expert"]
    steps["tree_action"] = pd.array(tree_actions, dtype="Int64")
    steps.loc[tree_actions < 0, "tree_action"] = pd.NA  # no tree yet at iteration 0
    steps["actor"] = np.where(seen["step_actor"], "expert", "tree")
    steps["weight"] = seen["step_weight"]
    data = pd.DataFrame(seen["data_x"], columns=names)
    data["expert_action"] = seen["data_y"]
    data["weight"] = seen["data_w"]
    data["draws"] = np.bincount(seen["idx"], minlength=len(data))
    return OpenIteration(spec, algo, seed, iteration, config.n_iterations, seen["beta"],
                         config.weighted, steps, data, tree, run.trees[iteration])


# ------------------------------------------------------------------------ 3. distribution shift
def visited_states(task: str | Task, drivers: dict[str, Any], seeds: Seq[int]
                   ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The states each driver (anything with ``act``) visits on the same episodes.

    Returns ``(states, episodes)``: one row per visited state (features and ``driver``), and
    one row per driver with its episodes' mean return and length.
    """
    spec = get_task(task)
    frames, rows = [], []
    for name, policy in drivers.items():
        seen: list[np.ndarray] = []

        def record(obs: np.ndarray, _actions: np.ndarray, seen: list[np.ndarray] = seen) -> None:
            seen.append(spec.features(obs))

        result = rollout(spec, policy.act, seeds, on_step=record)
        frame = pd.DataFrame(np.concatenate(seen), columns=list(spec.feature_names))
        frame["driver"] = name
        frames.append(frame)
        rows.append({"driver": name, "episodes": len(result.returns),
                     "mean_return": result.mean, "mean_length": float(np.mean(result.lengths)),
                     "states": len(frame)})
    return pd.concat(frames, ignore_index=True), pd.DataFrame(rows).set_index("driver")


def outside_support(states: pd.DataFrame, reference: str, features: Seq[str],
                    quantile: float = 0.005) -> pd.Series:
    """Share of each driver's states outside the reference driver's central box.

    The box spans the ``quantile`` .. ``1 - quantile`` range of every feature over the
    reference driver's states (the states a BC tree was trained on, when it is the expert).
    """
    ref = states[states.driver == reference][list(features)]
    low, high = ref.quantile(quantile), ref.quantile(1 - quantile)
    values = states[list(features)]
    outside = ((values < low) | (values > high)).any(axis=1)
    return (100 * outside.groupby(states.driver, sort=False).mean()).rename(
        f"% of states outside the {reference}'s central {100 * (1 - 2 * quantile):g} % box")


def shift_errors(states: pd.DataFrame, task: str | Task, expert: Any,
                 trees: dict[str, DecisionTreeClassifier]) -> pd.DataFrame:
    """How often each tree's action differs from the expert's, on each driver's states (%).

    A BC tree is accurate where it was trained (the expert's states) and errs where it drives
    itself: the distribution shift that the interactive loop corrects.
    """
    spec = get_task(task)
    x = states[list(spec.feature_names)].to_numpy(np.float32)
    expert_actions = expert.act(spec.observations(x))
    out = pd.DataFrame(index=pd.Index(list(dict.fromkeys(states.driver)), name="states of"))
    for name, tree in trees.items():
        wrong = CompiledTree(tree).predict(x) != expert_actions
        out[f"{name}: % actions != expert"] = (
            100 * pd.Series(wrong).groupby(states.driver.to_numpy(), sort=False).mean())
    return out


# ------------------------------------------------------------- 4. beta schedule and leaf limit
SCHEDULE_CHOICES: dict[str, schedules.Schedule] = {s.label: s for s in (
    schedules.linear(), schedules.exponential(0.5), schedules.first_only(),
    schedules.constant(1.0))}


def schedule_from_label(label: str) -> schedules.Schedule:
    """``"linear"``, ``"first_only"``, ``"exponential p=0.7"``, ``"constant 1"`` -> Schedule."""
    match = re.fullmatch(r"(linear|first_only)|exponential p=([0-9.]+)|constant ([0-9.]+)",
                         label.strip())
    if not match:
        raise ValueError(f"unknown schedule {label!r}; write 'linear', 'first_only', "
                         "'exponential p=0.5' or 'constant 1'")
    if match.group(1):
        return schedules.Schedule(match.group(1))
    if match.group(2):
        return schedules.exponential(float(match.group(2)))
    return schedules.constant(float(match.group(3)))


@dataclass(frozen=True)
class ScheduleView:
    """One (schedule, leaf limit) distillation: its tree, BT, sizes and retention."""

    schedule: str
    leaves: int
    tree: DecisionTreeClassifier
    bt: BehaviorTree
    facts: dict[str, Any]


def schedule_view(cfg: Config, task: str, algo: str, schedule: str, leaves: int, seed: int = 0
                  ) -> ScheduleView:
    """Imitation-BT (Q-gap resampling) with ``schedule`` and at most ``leaves`` leaves.

    Every step comes from the cache when it ran before (the distillation, the synthesis and the
    final evaluation on the profile's episodes), so a committed setting shows instantly.
    """
    from ibt.runs import grid

    spec = get_task(task)
    overrides = {"schedule": schedule_from_label(schedule), "max_leaf_nodes": int(leaves)}
    run = distill_cached(cfg, spec.name, algo, "imitation-bt", seed, **overrides)
    made = grid.synthesize_run(cfg, spec.name, algo, "imitation-bt", seed, "imitation-bt",
                                      **overrides)
    evaluation = grid.evaluate_tree(cfg, spec.name, run.best_tree)
    expert = grid.expert_evaluation(cfg, spec.name, algo)["mean_return"]
    facts = {"schedule": schedule, "leaf limit": int(leaves),
             "tree nodes": int(run.best_tree.tree_.node_count),
             "BT nodes": int(made["row"]["nodes"]), "BT conditions": int(made["row"]["conditions"]),
             "mean return": round(evaluation["mean_return"], 2),
             "retention_norm %": round(retention_norm(evaluation["mean_return"], expert,
                                                      spec.random_return()), 1),
             "episodes": cfg.final_episodes, "chosen iteration": run.best_index}
    return ScheduleView(schedule, int(leaves), run.best_tree, made["bt"], facts)


def schedule_table(cfg: Config, task: str, algo: str, schedule_labels: Seq[str],
                   leaf_limits: Seq[int], seed: int = 0) -> pd.DataFrame:
    """:func:`schedule_view`'s facts for every schedule and leaf limit."""
    return pd.DataFrame([schedule_view(cfg, task, algo, s, n, seed).facts
                         for s in schedule_labels for n in leaf_limits])


# ------------------------------------------------------------------------------ 6. exercises
def answer_iteration(it: OpenIteration) -> pd.Series:
    """Exercise 1: on how many of the steps the tree drove did it disagree with the expert,
    and what labels did those states get?"""
    steps = it.steps
    by_tree = steps[steps.actor == "tree"]
    wrong = by_tree[by_tree.tree_action != by_tree.expert_action]
    return pd.Series({
        "beta": round(it.beta, 3),
        "share of steps the expert drove": round(float((steps.actor == "expert").mean()), 3),
        "steps the tree drove": len(by_tree),
        "of which the tree's action differed from the expert's label": len(wrong),
        "labels those states got in the data set": "the expert's (every visited state is "
                                                   "labelled by the expert)",
        "share of the new data from states the tree led to (its own mistakes included)":
            round(float((steps.actor == "tree").mean()), 3)})


def answer_defaults(tree: DecisionTreeClassifier, task: str | Task) -> pd.DataFrame:
    """Exercise 2: the BT's size under each default-action strategy."""
    from ibt.synth.imitation import DEFAULT_STRATEGIES, imitation_bt

    spec = get_task(task)
    rows = []
    for strategy in DEFAULT_STRATEGIES:
        result = imitation_bt(tree, spec, default_strategy=strategy)
        types = result.bt.node_types()
        assert result.default_action is not None  # imitation_bt always chooses one
        rows.append({"default strategy": strategy,
                     "default action": spec.action_names[result.default_action],
                     "BT nodes": result.bt.node_count, "conditions": types["condition"]})
    return pd.DataFrame(rows).set_index("default strategy")
