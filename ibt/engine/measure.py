"""The measurement stage: every return of a tree, a BT, an agent or the random policy that
the engine, the studies and the pipeline roll out, each under its cache kind.

* ``returns`` (the pipeline, the ladder): every episode's return and length on a block of
  held-out episodes: :func:`measure` a stage's tree (every BT of it decides as it does; a
  command tree through its smallest BT, whose command table is the tree's),
  :func:`agent_returns`, :func:`random_returns`, :func:`bt_returns`, and :func:`returns_of`
  under which they all are; :func:`rolled` rolls a policy out now, uncached, with its wall time
  (the ladder's pace);
* the studies' summaries on the profile's final episodes: ``expert-eval``
  (:func:`expert_evaluation`), ``tree-eval`` (:func:`evaluate_tree`), ``bt-eval``
  (:func:`evaluate_bt`), ``protocol`` (:func:`protocol_evaluation`: the anchors' protocol),
  ``box-eval`` (:func:`command_tree_evaluation`: a command tree's BTs and the smallest's
  return, rolled out from its JSON); :func:`final_metrics` rolls a policy out uncached (the
  notebooks' comparisons).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine.agent import RANDOM_SEED, Agent
from ibt.engine.keys import bt_digest, doc_digest, tree_key
from ibt.engine.synthesis import command_bt, smallest_bt
from ibt.evaluate.rollouts import (
    FINAL_SEED_BASE,
    ReturnStats,
    episode_metrics,
    final_seeds,
    rollout,
)
from ibt.profiles import Config
from ibt.tasks.task import Task


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


def measure(cfg: Config, agent: Agent, tree: Any, bts: dict[str, Any], seeds: list[int]
            ) -> Returns:
    """The tree's returns on ``seeds`` (every BT of it decides as it does); a command tree is
    rolled out through its smallest BT (the command table is the BT's)."""
    return returns_of(cfg, agent.task, *policy(agent, tree, bts), seeds)


def policy(agent: Agent, tree: Any, bts: dict[str, Any]
           ) -> tuple[dict[str, Any], Callable[[], Any]]:
    """How a tree is measured: its identity in the cache, and its policy's maker."""
    from ibt.engine.learners import learner_of_tree
    from ibt.evaluate.policies import TreePolicy

    task = agent.task
    learner = learner_of_tree(tree)
    if learner is not None and learner.measured_as_bt:
        bt = bts[smallest_bt(bts)]
        if task.continuous:
            from ibt.synth.commands import CommandBTPolicy

            return {"bt": bt_digest(bt)}, lambda: CommandBTPolicy(task, bt).act
        from ibt.evaluate.policies import BTPolicy

        return {"bt": bt_digest(bt)}, lambda: BTPolicy(task, bt).act
    return {"tree": tree_key(tree)}, lambda: TreePolicy(task, tree).act


def agent_returns(cfg: Config, agent: Agent, seeds: list[int]) -> Returns:
    """The agent's returns on ``seeds`` (kind ``returns``, keyed on its digest)."""
    return returns_of(cfg, agent.task, {"algo": agent.algo, "expert_sha256": agent.digest},
                      lambda: agent.load().act, seeds)


def random_returns(cfg: Config, agent: Agent, seeds: list[int]) -> Returns:
    """The uniform random policy's returns on ``seeds`` over the agent's actions (kind
    ``returns``)."""
    return returns_of(cfg, agent.task, {"algo": "random", "policy": "uniform",
                                        "rng_seed": RANDOM_SEED}, agent.random_act, seeds)


def bt_returns(cfg: Config, task: Task, bt: Any, seeds: list[int]) -> Returns:
    """A BT's returns on ``seeds`` (kind ``returns``, keyed on its JSON document); a Box
    task's BT acts through its command table."""
    if task.continuous:
        from ibt.synth.commands import CommandBTPolicy

        act: Callable[[], Any] = lambda: CommandBTPolicy(task, bt).act  # noqa: E731
    else:
        from ibt.evaluate.policies import BTPolicy

        act = lambda: BTPolicy(task, bt).act  # noqa: E731
    return returns_of(cfg, task, {"bt": bt_digest(bt)}, act, seeds)


# --- the studies' summaries on the final episodes ---------------------------------------------


def final_metrics(task: Task, act: Any, episodes: int) -> dict[str, float]:
    """A policy's return statistics and the task's outcome rates over the first ``episodes``
    final-evaluation episodes, rolled out now (not cached)."""
    result = rollout(task, act, final_seeds(episodes))
    return {"mean_return": result.mean, "std_return": result.std,
            **episode_metrics(task, result)}


def expert_evaluation(cfg: Config, task: Task, algo: str) -> dict[str, float]:
    """The committed expert's return on the profile's final-evaluation episodes (kind
    ``expert-eval``)."""
    from ibt.experts.expert import expert_path, load_expert
    from ibt.files import file_digest

    params = {"task": task.name, "algo": algo, "episodes": cfg.final_episodes,
              "expert_sha256": file_digest(expert_path(task, algo, cfg.experts_dir))}

    def compute() -> dict[str, float]:
        expert = load_expert(task, algo, expert_path(task, algo, cfg.experts_dir))
        result = rollout(task, expert.act, final_seeds(cfg.final_episodes))
        return {"mean_return": result.mean, "std_return": result.std}

    return load_or_compute("expert-eval", params, compute, cache_dir=cfg.cache_dir,
                           codec="json", refresh=cfg.refresh)


def evaluate_tree(cfg: Config, task: Task, tree: Any) -> dict[str, float]:
    """A decision tree's final evaluation (kind ``tree-eval``, on the tree's exact
    structure)."""
    from ibt.cache.store import tree_digest
    from ibt.evaluate.policies import TreePolicy

    return _final_evaluation(cfg, task, "tree-eval", {"tree": tree_digest(tree)},
                             lambda: TreePolicy(task, tree).act)


def evaluate_bt(cfg: Config, task: Task, bt: Any) -> dict[str, float]:
    """A BT's final evaluation, rolled out in the environment (kind ``bt-eval``, on its
    JSON)."""
    from ibt.evaluate.policies import BTPolicy

    return _final_evaluation(cfg, task, "bt-eval", {"bt": bt_digest(bt)},
                             lambda: BTPolicy(task, bt).act)


def _final_evaluation(cfg: Config, task: Task, kind: str, what: dict[str, str], act: Any
                      ) -> dict[str, float]:
    """``act()``'s policy on the profile's final episodes, cached as ``kind`` under ``what``
    (a tree's or a BT's digest)."""
    params = {"task": task.name, "episodes": cfg.final_episodes, **what}
    return load_or_compute(kind, params,
                           lambda: final_metrics(task, act(), cfg.final_episodes),
                           cache_dir=cfg.cache_dir, codec="json", refresh=cfg.refresh)


def protocol_evaluation(cfg: Config, task: Task, bt: Any, episodes: int = 1000,
                        threshold: float | None = 200.0) -> dict[str, Any]:
    """The anchors' protocol: the BT rolled out from its own JSON on ``episodes`` final
    episodes (seeds disjoint from every training, refinement and selection seed): mean,
    standard deviation and the share of episodes at or above ``threshold`` (kind
    ``protocol``)."""
    import numpy as np

    from ibt.bt.model import BehaviorTree

    bt = BehaviorTree.from_json(bt.to_json())  # exactly what the committed file holds
    params = {"task": task.name, "episodes": episodes, "threshold": threshold,
              "bt": bt_digest(bt)}

    def compute() -> dict[str, Any]:
        from ibt.evaluate.policies import BTPolicy

        result = rollout(task, BTPolicy(task, bt).act, final_seeds(episodes))
        share = None if threshold is None else float(np.mean(result.returns >= threshold))
        return {"episodes": episodes, "mean_return": result.mean, "std_return": result.std,
                "share_at_threshold": share, "threshold": threshold}

    return load_or_compute("protocol", params, compute, cache_dir=cfg.cache_dir, codec="json",
                           refresh=cfg.refresh)


def command_tree_evaluation(cfg: Config, task: Task, arrays: Any,
                            episodes: int | None = None) -> dict[str, Any]:
    """Every front synthesiser's BT of a command tree (nodes each), the smallest one's JSON
    document, and its final-episode statistics rolled out from that JSON text (kind
    ``box-eval``)."""
    import json

    import numpy as np

    from ibt.bt.model import BehaviorTree
    from ibt.synth.commands import CommandBTPolicy
    from ibt.synth.registry import front_synthesisers

    n = episodes or cfg.final_episodes
    synthesisers = front_synthesisers()
    params = {"task": task.name, "tree": doc_digest(arrays.to_doc()), "episodes": n,
              "synthesisers": list(synthesisers)}

    def compute() -> dict[str, Any]:
        out: dict[str, Any] = {}
        bts = {}
        for method in synthesisers:
            bts[method] = command_bt(arrays, task, method)
            out[f"nodes_{method.replace('-', '_')}"] = bts[method].node_count
        smallest = smallest_bt(bts)
        text = bts[smallest].to_json()
        policy = CommandBTPolicy(task, BehaviorTree.from_json(text))
        result = rollout(task, policy.act, final_seeds(n))
        returns = np.asarray(result.returns)
        out.update({"bt_method": smallest, "bt_nodes": bts[smallest].node_count,
                    "bt": json.loads(text), "episodes": n, "mean_return": float(returns.mean()),
                    "std_return": float(returns.std()),
                    "share_200": float((returns >= 200).mean())})
        return out

    return load_or_compute("box-eval", params, compute, cache_dir=cfg.cache_dir, codec="json",
                           refresh=cfg.refresh)
