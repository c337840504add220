"""Editing a synthesised BT by hand (stage 5 of ``notebooks/08_lesson.ipynb``): a readable
guard (:func:`guard`, from tests such as ``["location", "==", "charger"]``) put among the root
Selector's children (:func:`add_guard`), the states where the edit changes a decision
(:func:`decision_diff`, over :func:`all_states` of an integer-featured task), and the edited BT
beside the original on variants of the environment (:func:`evaluate_variants`,
:func:`guard_sweep`). Plain data; the views are in :mod:`ibt.views.widgets`.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence as Seq
from typing import Any

import numpy as np
import pandas as pd

from ibt.bt.executors import as_features
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Node, Selector, Sequence
from ibt.evaluate.rollouts import rollout
from ibt.tasks.catalogue import Task, get_task


# ---------------------------------------------------------------------------- 5. edit the BT
def feature_test(bt: BehaviorTree, feature: str, op: str, value: float | str) -> Node:
    """One readable test as BT nodes: ``<=`` / ``>`` on any feature, ``==`` / ``!=`` on a
    categorical one (``["location", "==", "charger"]``)."""
    if feature not in bt.feature_names:
        raise ValueError(f"unknown feature {feature!r}; the BT has {', '.join(bt.feature_names)}")
    f = bt.feature_names.index(feature)
    if op in ("<=", ">"):
        return Condition(f, op, float(value))
    labels = dict(bt.value_labels).get(f)
    if op not in ("==", "!=") or labels is None or value not in labels:
        raise ValueError(f"{feature} {op} {value!r}: use <= or > with a number, or == / != with "
                         f"one of the feature's values {list(labels or [])}")
    k, last = labels.index(value), len(labels) - 1
    below, above = Condition(f, "<=", k - 0.5), Condition(f, ">", k + 0.5)
    if op == "==":
        parts = [c for c, keep in ((Condition(f, ">", k - 0.5), k > 0),
                                   (Condition(f, "<=", k + 0.5), k < last)) if keep]
        return parts[0] if len(parts) == 1 else Sequence(tuple(parts))
    parts = [c for c, keep in ((below, k > 0), (above, k < last)) if keep]
    return parts[0] if len(parts) == 1 else Fallback(tuple(parts))


def guard(bt: BehaviorTree, when: Seq[Seq[Any]], action: str) -> Node:
    """``Sequence(test, ..., action)``: do ``action`` when every test of ``when`` holds."""
    if action not in bt.action_names:
        raise ValueError(f"unknown action {action!r}; the BT has {', '.join(bt.action_names)}")
    tests = [feature_test(bt, *test) for test in when]
    return Sequence((*tests, Action(bt.action_names.index(action))))


def add_guard(bt: BehaviorTree, node: Node, position: int = 0) -> BehaviorTree:
    """A copy of ``bt`` with ``node`` inserted among the root Selector's children.

    ``position`` 0 puts it first (it overrides every rule); ``-1`` just before the last child
    (the default action), where it acts only where no rule fired.
    """
    if not isinstance(bt.root, Selector):
        raise ValueError("add_guard edits a synthesised BT, whose root is a Selector")
    children = list(bt.root.children)
    children.insert(position, node)  # list.insert: -1 puts it before the last child
    return BehaviorTree(Selector(tuple(children)), bt.feature_names, bt.action_names,
                        bt.value_labels)


def all_states(task: str | Task) -> np.ndarray:
    """Every state of an integer-featured task's box (PackageDelivery: 1,188)."""
    spec = get_task(task)
    if not spec.integer_features:
        raise ValueError(f"{spec.name} has continuous features: sample states instead")
    ranges = [range(int(lo), int(hi) + 1) for lo, hi in zip(spec.low, spec.high, strict=True)]
    return np.array(list(itertools.product(*ranges)), dtype=np.float32)


def decision_diff(before: BehaviorTree, after: BehaviorTree, states: np.ndarray) -> pd.DataFrame:
    """The states where two BTs decide differently, readable (categories by their labels)."""
    x = as_features(states)
    old, new = before.decide(x), after.decide(x)
    changed = np.flatnonzero(old != new)
    labels = dict(before.value_labels)
    rows = []
    for i in changed:
        row = {name: (labels[f][int(x[i, f])] if f in labels else x[i, f])
               for f, name in enumerate(before.feature_names)}
        row.update({"before": before.action_names[old[i]], "after": after.action_names[new[i]]})
        rows.append(row)
    return pd.DataFrame(rows, columns=[*before.feature_names, "before", "after"])


def expert_agreement(bt: BehaviorTree, expert: Any, task: str | Task, states: np.ndarray
                     ) -> float:
    """Percentage of ``states`` on which ``bt`` chooses the expert's action."""
    spec = get_task(task)
    expert_actions = expert.act(spec.observations(states))
    return float(100 * np.mean(bt.decide(states) == expert_actions))


def evaluate_variants(task: str | Task, policies: dict[str, Any],
                      variants: dict[str, dict[str, Any]], seeds: Seq[int]) -> pd.DataFrame:
    """Every policy on the same episodes of every environment variant (``{label: env
    kwargs}``, e.g. ``{"drain 2": {"drain_scale": 2}}``): return and the task's outcome rates."""
    from ibt.evaluate.rollouts import episode_metrics

    spec = get_task(task)
    rows = []
    for variant, kwargs in variants.items():
        for name, policy in policies.items():
            result = rollout(spec, policy.act, seeds, env_kwargs=kwargs,
                             n_envs=min(len(seeds), 100))  # one batch: seeded, so same episodes
            rows.append({"environment": variant, "policy": name, "episodes": len(seeds),
                         "mean_return": result.mean, "std_return": result.std,
                         **episode_metrics(spec, result)})
    return pd.DataFrame(rows)


def guard_sweep(bt: BehaviorTree, when: Seq[Seq[Any]], action: str, values: Seq[float],
                task: str | Task, variants: dict[str, dict[str, Any]], seeds: Seq[int]
                ) -> pd.DataFrame:
    """The guard of :func:`guard` put first in ``bt`` with its first test's value set to each
    of ``values``, evaluated on every variant (one row per value and variant)."""
    from ibt.evaluate.policies import BTPolicy

    spec = get_task(task)
    rows = []
    for value in values:
        tests = [[*when[0][:2], value], *when[1:]]
        edited = add_guard(bt, guard(bt, tests, action))
        table = evaluate_variants(spec, {"edited": BTPolicy(spec, edited)}, variants, seeds)
        rows.append(table.drop(columns="policy").assign(
            **{f"{when[0][0]} {when[0][1]}": value, "states changed": len(
                decision_diff(bt, edited, all_states(spec)))}))
    return pd.concat(rows, ignore_index=True)
