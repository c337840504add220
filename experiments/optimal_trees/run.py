"""Optimal small trees (ConTree) versus CART as the start of refinement, on LunarLander-v3.

A measured experiment, not part of the package. Four steps, each reading the previous one's
plain-data output from ``--out`` (npz / JSON, never pickles):

* ``collect``: the Imitation-BT interactive loop (``ibt.distill.loop.interactive_loop``, the
  method ``imitation-bt``, CART at ``--leaves``) on the committed expert; a recording learner
  keeps the last iteration's weight-resampled aggregate (what the loop's CART was fitted on),
  the raw aggregate with the expert's weights, and the loop's best tree (the pipeline's start);
* ``fit``: at depth 2 and 3, CART (the project's settings: ``max_leaf_nodes`` = 2**depth, and
  ``max_depth`` = depth) and ConTree (``pycontree``, optimal misclassification at that depth,
  with a time limit) on the same resampled data; weighted training accuracy of each;
* ``evaluate``: every tree as a policy on the 100 final-evaluation episodes
  (``ibt.evaluate.rollouts.final_seeds``), the same seeds for all; with ``--refine`` each start
  is refined by return (``ibt.refine.by_return.refine``, a small budget, the same for every
  tree) and evaluated again on the same episodes;
* ``paired``: two trees' returns on the same episodes, start and each refinement, as a paired
  difference with its standard error;
* ``costs`` (STreeD part): the expert's per-action regret on the raw aggregate's states (DQN:
  Q-gap to the best action; PPO: log-probability gap to the best action), to npz;
* ``streed``: CART at ``nodes + 1`` leaves and STreeD (``pystreed``, optimal instance
  cost-sensitive tree with at most ``nodes`` branching nodes, on quantile-binarised features)
  fitted to those costs; added to the ``fit`` step's tree file, so ``evaluate`` and ``paired``
  take them as they are.

pycontree and pystreed are not project dependencies: install them into a separate folder and
put that folder on PYTHONPATH after the worktree (see RESULTS.md). Seeds are explicit; the same
command gives the same numbers (a fit stopped by its time limit aside).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.distill.loop import ClassifierLearner, interactive_loop
from ibt.engine.agent import committed_agent
from ibt.engine.budgets import distill_config
from ibt.evaluate.policies import TreePolicy
from ibt.evaluate.rollouts import final_seeds, rollout
from ibt.profiles import config as profile_config
from ibt.refine.tree_arrays import TreeArrays, tree_arrays_from_nested
from ibt.tasks.catalogue import get_task

TASK = "LunarLander-v3"
SEED = 0


@dataclass
class RecordingLearner:
    """The loop's own CART learner, keeping what it was given: every labelled batch (features,
    actions, weights) and the last (resampled) fitting set."""

    inner: ClassifierLearner
    task: Any
    raw: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    last_fit: tuple[np.ndarray, np.ndarray] | None = None

    def label(self, expert: Any, obs: np.ndarray, weighted: bool) -> Any:
        actions, weights = self.inner.label(expert, obs, weighted)
        self.raw.append((self.task.features(obs), actions, weights))
        return actions, weights

    def fit(self, x: np.ndarray, y: np.ndarray) -> Any:
        self.last_fit = (x, y)
        return self.inner.fit(x, y)

    def signature(self, tree: Any) -> bytes:
        return self.inner.signature(tree)

    def predictor(self, tree: Any) -> Any:
        return self.inner.predictor(tree)

    def mix(self, *args: Any) -> Any:
        return self.inner.mix(*args)


def tree_doc(tree: DecisionTreeClassifier) -> dict[str, Any]:
    """A tree as plain JSON (its flat arrays)."""
    a = TreeArrays.from_sklearn(tree)
    return {"feature": a.feature.tolist(), "threshold": a.threshold.tolist(),
            "left": a.left.tolist(), "right": a.right.tolist(), "action": a.action.tolist(),
            "samples": a.samples.tolist(), "n_features": a.n_features,
            "n_actions": a.n_actions}


def tree_from_doc(doc: dict[str, Any]) -> DecisionTreeClassifier:
    arrays = TreeArrays(*(np.asarray(doc[k], dtype=np.float64 if k in ("threshold", "samples")
                                     else np.int64)
                          for k in ("feature", "threshold", "left", "right", "action",
                                    "samples")), doc["n_features"], doc["n_actions"])
    return arrays.to_sklearn()


def write_json(path: Path, doc: Any) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, path)


def collect(out: Path, leaves: int, iterations: int, algo: str) -> None:
    cfg = profile_config("paper", cache_dir=out / "cache", progress=False)
    task = get_task(TASK)
    agent = committed_agent(task, algo)
    config = distill_config(cfg, task, max_leaf_nodes=leaves, n_iterations=iterations)
    learner = RecordingLearner(ClassifierLearner(config, SEED), task)
    start = time.perf_counter()
    run = interactive_loop(task, agent.load(), config, SEED, learner, progress=False)
    x_raw = np.concatenate([r[0] for r in learner.raw])
    assert learner.last_fit is not None
    x_fit, y_fit = learner.last_fit
    tmp = out / f"data_L{leaves}.tmp.npz"
    np.savez_compressed(tmp, x_raw=x_raw, y_raw=np.concatenate([r[1] for r in learner.raw]),
                        w_raw=np.concatenate([r[2] for r in learner.raw]), x_fit=x_fit,
                        y_fit=y_fit)
    os.replace(tmp, out / f"data_L{leaves}.npz")
    write_json(out / f"loop_L{leaves}.json", {
        "algo": algo, "config": config.as_params(), "iterations": run.iterations,
        "best_index": run.best_index, "best_tree": tree_doc(run.best_tree),
        "wall_seconds": time.perf_counter() - start})
    print(f"collect L={leaves}: {len(x_raw)} labels, best iteration {run.best_index} "
          f"({run.iterations[run.best_index]['selection_mean']:.1f}), "
          f"{time.perf_counter() - start:.0f} s")


def contree_to_sklearn(model: Any, x: np.ndarray, n_actions: int) -> DecisionTreeClassifier:
    """A fitted ConTree as a scikit-learn tree (same ``x <= t`` goes left), node weights
    counted on ``x`` (refinement breaks ties with them)."""

    def build(node: Any, rows: np.ndarray) -> tuple:
        if node.is_leaf_node():
            return ("leaf", int(node.get_label()), float(rows.sum()))
        f, t = int(node.get_split_feature()), float(node.get_split_threshold())
        go_left = x[:, f] <= t
        return ("split", f, t, build(node.get_left(), rows & go_left),
                build(node.get_right(), rows & ~go_left), float(rows.sum()))

    nested = build(model.get_tree(), np.ones(len(x), dtype=bool))
    return tree_arrays_from_nested(nested, x.shape[1], n_actions).to_sklearn()


def weighted_accuracy(tree: DecisionTreeClassifier, x: np.ndarray, y: np.ndarray,
                      w: np.ndarray | None = None) -> float:
    hit = tree.predict(x) == y
    return float(np.average(hit, weights=w))


def fit(out: Path, leaves: int, time_limit: float, depths: list[int]) -> None:
    from pycontree import ConTree

    data = np.load(out / f"data_L{leaves}.npz")
    # the features as the trees compare them: float32 widened to float64 (sklearn's way)
    x_fit = data["x_fit"].astype(np.float32).astype(np.float64)
    y_fit = data["y_fit"].astype(np.int64)
    x_raw = data["x_raw"].astype(np.float32).astype(np.float64)
    y_raw, w_raw = data["y_raw"].astype(np.int64), data["w_raw"]
    n_actions = get_task(TASK).n_actions
    loop = json.loads((out / f"loop_L{leaves}.json").read_text())
    trees: dict[str, Any] = {f"loop-best-L{leaves}": {"tree": loop["best_tree"],
                                                       "fit_seconds": None}}
    for depth in depths:
        candidates = {
            f"cart-L{2 ** depth}": DecisionTreeClassifier(max_leaf_nodes=2 ** depth,
                                                          random_state=SEED),
            f"cart-d{depth}": DecisionTreeClassifier(max_depth=depth, random_state=SEED)}
        for name, model in candidates.items():
            t0 = time.process_time()
            model.fit(x_fit, y_fit)
            trees[name] = {"tree": tree_doc(model), "fit_seconds": time.process_time() - t0}
        t0 = time.perf_counter()
        ct = ConTree(max_depth=depth, time_limit=time_limit).fit(x_fit, y_fit)
        within = bool(ct._config.is_within_time_limit())
        trees[f"contree-d{depth}"] = {
            "tree": tree_doc(contree_to_sklearn(ct, x_fit, n_actions)),
            "fit_seconds": time.perf_counter() - t0, "optimal_within_limit": within}
    for name, entry in trees.items():
        tree = tree_from_doc(entry["tree"])
        entry["acc_resampled"] = weighted_accuracy(tree, x_fit, y_fit)
        entry["acc_weighted_raw"] = weighted_accuracy(tree, x_raw, y_raw, w_raw)
        entry["acc_unweighted_raw"] = weighted_accuracy(tree, x_raw, y_raw)
        entry["leaves"] = int(tree.get_n_leaves())
        entry["nodes"] = int(tree.tree_.node_count)
        print(f"{name:16s} leaves {entry['leaves']:2d} acc(resampled) "
              f"{entry['acc_resampled']:.4f} acc(w raw) {entry['acc_weighted_raw']:.4f} "
              f"fit {entry['fit_seconds']}")
    write_json(out / f"trees_L{leaves}.json", trees)


def evaluate(out: Path, leaves: int, episodes: int, refine_episodes: int,
             names: list[str] | None, refine_seed: int = SEED) -> None:
    task = get_task(TASK)
    seeds = final_seeds(episodes)
    trees = json.loads((out / f"trees_L{leaves}.json").read_text())
    path = out / f"eval_L{leaves}.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for name, entry in trees.items():
        if names and name not in names:
            continue
        tree = tree_from_doc(entry["tree"])
        row = results.setdefault(name, {})
        row.update(score(task, tree, seeds), leaves=entry["leaves"], nodes=entry["nodes"])
        print(f"{name:16s} start  {row['mean']:8.1f} +- {row['std']:6.1f} "
              f"share>=200 {row['share_200']:.2f} nodes {row['nodes']}")
        if refine_episodes:
            from dataclasses import replace

            from ibt.refine.by_return import refine, task_config

            config = replace(task_config(task), stages=("cma", "leaves"),
                             episodes=refine_episodes)
            t0 = time.process_time()
            refined = refine(tree, task, config, refine_seed, progress=False).best_tree
            key = f"refined_{refine_episodes}" + (f"_s{refine_seed}" if refine_seed else "")
            row[key] = {**score(task, refined, seeds),
                              "nodes": int(refined.tree_.node_count),
                              "leaves": int(refined.get_n_leaves()),
                              "refine_episodes": refine_episodes,
                              "refine_cpu_seconds": time.process_time() - t0,
                              "tree": tree_doc(refined)}
            r = row[key]
            print(f"{name:16s} refined {r['mean']:8.1f} +- {r['std']:6.1f} "
                  f"share>=200 {r['share_200']:.2f} nodes {r['nodes']}")
        write_json(path, results)


def paired(out: Path, leaves: int, first: str, second: str, episodes: int) -> None:
    """The paired difference ``second - first`` on the same final episodes, for the starts and
    every refinement both trees have (refined trees re-scored from their stored arrays)."""
    task = get_task(TASK)
    seeds = final_seeds(episodes)
    trees = json.loads((out / f"trees_L{leaves}.json").read_text())
    results = json.loads((out / f"eval_L{leaves}.json").read_text())
    stages = ["start", *sorted(k for k in results[first] if k.startswith("refined_")
                               and k in results[second])]
    rows = []
    for stage in stages:
        returns = []
        for name in (first, second):
            doc = trees[name]["tree"] if stage == "start" else results[name][stage]["tree"]
            returns.append(np.asarray(score(task, tree_from_doc(doc), seeds)["returns"]))
        diff = returns[1] - returns[0]
        rows.append({"stage": stage, "first": first, "second": second,
                     "first_mean": float(returns[0].mean()),
                     "second_mean": float(returns[1].mean()),
                     "diff_mean": float(diff.mean()),
                     "diff_se": float(diff.std(ddof=1) / np.sqrt(len(diff)))})
        r = rows[-1]
        print(f"{stage:18s} {first} {r['first_mean']:7.1f}  {second} {r['second_mean']:7.1f}  "
              f"diff {r['diff_mean']:+6.1f} +- {r['diff_se']:.1f} (paired SE)")
    write_json(out / f"paired_L{leaves}_{first}_{second}.json", rows)


def score(task: Any, tree: DecisionTreeClassifier, seeds: list[int]) -> dict[str, Any]:
    returns = rollout(task, TreePolicy(task, tree).act, seeds).returns
    return {"mean": float(np.mean(returns)), "std": float(np.std(returns)),
            "share_200": float(np.mean(returns >= 200)), "episodes": len(seeds),
            "returns": [float(r) for r in returns]}


# --- STreeD (pystreed): optimal cost-sensitive trees under a branching-node budget ----------

PPO_COST_CLIP = 4.0  # nats: an action e**4 (about 55) times less likely than the best one


def costs(out: Path, leaves: int) -> None:
    """The committed expert's (the one ``collect`` used) regret of each action on the raw
    aggregate's states: DQN ``max_a' Q(s, a') - Q(s, a)``; PPO ``log pi(best|s) - log pi(a|s)``
    (``streed`` clips it)."""
    task = get_task(TASK)
    algo = json.loads((out / f"loop_L{leaves}.json").read_text())["algo"]
    expert = committed_agent(task, algo).load()
    data = np.load(out / f"data_L{leaves}.npz")
    x_raw = data["x_raw"]
    scores = np.concatenate([expert.scores(task.observations(x_raw[i:i + 4096]))
                             for i in range(0, len(x_raw), 4096)])
    # the same states, actions and weights as the loop's labels (a check on the round trip)
    assert np.array_equal(scores.argmax(axis=1), data["y_raw"])
    spread = scores.max(axis=1) - scores.min(axis=1)
    assert np.allclose(spread, data["w_raw"], rtol=1e-4, atol=1e-4)
    regret = scores.max(axis=1, keepdims=True) - scores
    np.savez_compressed(out / f"costs_L{leaves}.npz", scores=scores, regret=regret)
    print(f"costs L={leaves} ({algo}): {len(regret)} states, mean best-vs-worst regret "
          f"{regret.max(axis=1).mean():.3f}")


def action_costs(out: Path, leaves: int, clip: float) -> np.ndarray:
    """The fitting costs: DQN's regret as it is, PPO's clipped at ``clip`` nats."""
    regret = np.load(out / f"costs_L{leaves}.npz")["regret"]
    algo = json.loads((out / f"loop_L{leaves}.json").read_text())["algo"]
    return regret if algo == "dqn" else np.minimum(regret, clip)


def binarize(x: np.ndarray, n_thresholds: int) -> tuple[np.ndarray, list[tuple[int, float]]]:
    """``x <= t`` columns: a feature with two values at their midpoint, any other at its
    ``n_thresholds`` quantiles (pystreed's own 'quantile' strategy). Returns the 0/1 matrix
    and each column's (feature, threshold)."""
    columns: list[tuple[int, float]] = []
    for f in range(x.shape[1]):
        values = np.unique(x[:, f])
        if len(values) <= n_thresholds + 1:
            cuts = (values[:-1] + values[1:]) / 2
        else:
            cuts = np.unique(np.quantile(x[:, f], np.linspace(0, 1, n_thresholds + 2)[1:-1]))
        columns += [(f, float(t)) for t in cuts]
    bits = np.stack([x[:, f] <= t for f, t in columns], axis=1).astype(np.intc)
    return bits, columns


def streed_to_sklearn(node: Any, columns: list[tuple[int, float]], x: np.ndarray,
                      n_actions: int) -> DecisionTreeClassifier:
    """A fitted STreeD tree on ``x <= t`` bits as a scikit-learn tree. STreeD's left child
    takes bit 0 (``x > t``), so the children swap. Node weights counted on ``x``."""

    def build(node: Any, rows: np.ndarray) -> tuple:
        if node.is_leaf_node():
            return ("leaf", int(node.label), float(rows.sum()))
        f, t = columns[int(node.feature)]
        go_left = x[:, f] <= t
        return ("split", f, t, build(node.right_child, rows & go_left),
                build(node.left_child, rows & ~go_left), float(rows.sum()))

    nested = build(node, np.ones(len(x), dtype=bool))
    return tree_arrays_from_nested(nested, x.shape[1], n_actions).to_sklearn()


def fit_streed(out: Path, leaves: int, nodes_list: list[int], depth: int, n_thresholds: int,
               time_limit: float, clip: float, tag: str) -> None:
    """CART at ``nodes + 1`` leaves (the project's) and STreeD (instance cost-sensitive, at
    most ``nodes`` branching nodes and ``depth``) on the raw aggregate with the expert's
    per-action costs; identical binarised states are merged (their costs summed: the same
    objective). Added to ``trees_L{leaves}.json``."""
    from pystreed import STreeDInstanceCostSensitiveClassifier

    data = np.load(out / f"data_L{leaves}.npz")
    x_fit = data["x_fit"].astype(np.float32).astype(np.float64)
    y_fit = data["y_fit"].astype(np.int64)
    x_raw = data["x_raw"].astype(np.float32).astype(np.float64)
    y_raw, w_raw = data["y_raw"].astype(np.int64), data["w_raw"]
    cost = action_costs(out, leaves, clip)
    algo = json.loads((out / f"loop_L{leaves}.json").read_text())["algo"]
    # every tree's mean cost under the default costs, and its unclipped regret
    default_cost, regret = action_costs(out, leaves, PPO_COST_CLIP), action_costs(out, leaves,
                                                                                   np.inf)
    n_actions = get_task(TASK).n_actions
    path = out / f"trees_L{leaves}.json"
    trees = json.loads(path.read_text()) if path.exists() else {}
    bits, columns = binarize(x_raw, n_thresholds)
    cells, inverse = np.unique(bits, axis=0, return_inverse=True)
    cell_cost = np.zeros((len(cells), cost.shape[1]))
    np.add.at(cell_cost, inverse.reshape(-1), cost)
    print(f"STreeD data: {len(x_raw)} states, {bits.shape[1]} binary features, "
          f"{len(cells)} distinct cells")
    for nodes in nodes_list:
        name = f"cart-L{nodes + 1}"
        if name not in trees:
            t0 = time.process_time()
            model = DecisionTreeClassifier(max_leaf_nodes=nodes + 1, random_state=SEED)
            model.fit(x_fit, y_fit)
            trees[name] = {"tree": tree_doc(model), "fit_seconds": time.process_time() - t0}
        st = STreeDInstanceCostSensitiveClassifier(
            max_depth=depth, max_num_nodes=nodes, time_limit=time_limit, random_seed=SEED)
        t0 = time.perf_counter()
        st.fit(cells, cell_cost)
        seconds = time.perf_counter() - t0
        tree = streed_to_sklearn(st.get_tree(), columns, x_fit, n_actions)
        assert np.array_equal(tree.predict(x_raw), st.predict(bits)), "conversion mismatch"
        trees[f"streed-n{nodes}{tag}"] = {
            "tree": tree_doc(tree), "fit_seconds": seconds,
            "optimal_within_limit": bool(st.fit_result.is_optimal()),
            "streed": {"cost_clip": None if algo == "dqn" else clip, "max_depth": depth,
                       "max_num_nodes": nodes, "time_limit": time_limit,
                       "n_thresholds": n_thresholds, "binary_features": bits.shape[1],
                       "cells": len(cells), "objective": float(st.fit_result.score()),
                       "depth": int(st.fit_result.tree_depth()),
                       "branching_nodes": int(st.fit_result.tree_nodes())}}
    for name, entry in trees.items():
        tree = tree_from_doc(entry["tree"])
        entry["acc_resampled"] = weighted_accuracy(tree, x_fit, y_fit)
        entry["acc_weighted_raw"] = weighted_accuracy(tree, x_raw, y_raw, w_raw)
        entry["acc_unweighted_raw"] = weighted_accuracy(tree, x_raw, y_raw)
        chosen = (np.arange(len(x_raw)), tree.predict(x_raw).astype(np.int64))
        entry["mean_cost_raw"] = float(default_cost[chosen].mean())
        entry["mean_regret_raw"] = float(regret[chosen].mean())
        entry["leaves"] = int(tree.get_n_leaves())
        entry["nodes"] = int(tree.tree_.node_count)
        print(f"{name:18s} leaves {entry['leaves']:2d} acc(w raw) "
              f"{entry['acc_weighted_raw']:.4f} mean cost {entry['mean_cost_raw']:.4f} "
              f"fit {entry['fit_seconds']} optimal {entry.get('optimal_within_limit')}")
    write_json(path, trees)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("step", choices=("collect", "fit", "evaluate", "paired", "costs",
                                         "streed"))
    parser.add_argument("--out", type=Path, default=Path("/tmp/contree_out"))
    parser.add_argument("--algo", default="ppo", help="the committed expert (collect)")
    parser.add_argument("--leaves", type=int, default=8, help="the loop's CART leaf limit")
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--time-limit", type=float, default=300.0)
    parser.add_argument("--depths", type=int, nargs="+", default=[2, 3])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--refine-episodes", type=int, default=0)
    parser.add_argument("--refine-seed", type=int, default=SEED)
    parser.add_argument("--pair", nargs=2, default=["cart-L8", "contree-d3"],
                        help="paired: the two trees compared (second minus first)")
    parser.add_argument("--only", nargs="*", help="evaluate only these trees")
    parser.add_argument("--clip", type=float, default=PPO_COST_CLIP,
                        help="streed: PPO's cost cap in nats")
    parser.add_argument("--nodes", type=int, nargs="+", default=[7, 3],
                        help="streed: branching-node budgets")
    parser.add_argument("--streed-depth", type=int, default=4)
    parser.add_argument("--thresholds", type=int, default=10,
                        help="streed: quantile thresholds per continuous feature")
    parser.add_argument("--tag", default="", help="streed: a suffix for the trees' names")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.step == "collect":
        collect(args.out, args.leaves, args.iterations, args.algo)
    elif args.step == "fit":
        fit(args.out, args.leaves, args.time_limit, args.depths)
    elif args.step == "costs":
        costs(args.out, args.leaves)
    elif args.step == "streed":
        fit_streed(args.out, args.leaves, args.nodes, args.streed_depth, args.thresholds,
                   args.time_limit, args.clip, args.tag)
    elif args.step == "paired":
        paired(args.out, args.leaves, *args.pair, args.episodes)
    else:
        evaluate(args.out, args.leaves, args.episodes, args.refine_episodes, args.only,
                 args.refine_seed)


if __name__ == "__main__":
    main()
