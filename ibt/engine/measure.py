"""The measurement stage: a policy's returns on held-out episodes, cached (kind ``returns``).

A tree, a BT, an agent or the random policy is measured here: :func:`measure` a stage's tree
(every BT of it decides as it does; a command tree through its smallest BT, whose command
table is the tree's), :func:`returns_of` any policy under its identity in the cache,
:func:`rolled` a policy now, uncached, with its wall time (the ladder's pace).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine.agent import Agent
from ibt.engine.keys import bt_digest, tree_key
from ibt.engine.synthesis import smallest_bt
from ibt.evaluate.rollouts import FINAL_SEED_BASE, ReturnStats, rollout
from ibt.profiles import Config


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
    from ibt.evaluate.policies import TreePolicy
    from ibt.refine.commands import CommandArrays

    task = agent.task
    if isinstance(tree, CommandArrays):
        from ibt.synth.commands import CommandBTPolicy

        bt = bts[smallest_bt(bts)]
        return {"bt": bt_digest(bt)}, lambda: CommandBTPolicy(task, bt).act
    return {"tree": tree_key(tree)}, lambda: TreePolicy(task, tree).act
