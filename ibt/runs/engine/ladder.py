"""The anytime ladder: smallest leaf limit first, stopped by the target, a deadline or a signal.

Two passes over the leaf limits (the rungs), in increasing order:

1. **imitation**: at each rung, for each learner (axis-aligned, then relational at the same
   limit; a Box task's regression learner), distil, then refine by return. The ladder stops
   at the first rung whose best BT keeps the target.
2. **structure search** (discrete actions): at each rung below that one (every rung when no
   BT kept the target), the search by return from that rung's distilled and refined trees,
   with restarts; it stops at the first rung whose searched BT keeps the target.

Imitation runs first over all rungs because it is cheap next to a search: on a task where a
small tree imitates the agent well the answer comes in seconds, and where none does, a search
at the smallest rung cannot spend the whole budget before the larger rungs were even tried.

The ladder is anytime: between steps (each one cached whole) it checks the deadline and the
caller's ``on_step`` callback; Ctrl-C or SIGTERM inside a step ends that step unfinished
(nothing of it is cached) and the ladder returns what it has, marked as stopped. A rerun with
a longer deadline resumes from the cache.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from ibt.evaluate.rollouts import retention_norm
from ibt.profiles import Config
from ibt.runs.engine import stages
from ibt.runs.engine.agent import Agent
from ibt.signals import STOP_SIGNALS, stop_reason


@dataclass
class Candidate:
    """One tree of the front (distilled, refined or searched at a leaf limit) and its BTs."""

    leaf_limit: int
    stage: str  # "distilled", "refined" or "searched"
    tree: Any
    bts: dict[str, Any]  # synthesiser -> verified BehaviorTree
    mean_return: float  # on the choice episodes (the tree's; every BT decides as it does)
    std_return: float
    retention: float  # random-normalised, %, on the choice episodes
    relational: bool = False  # the tree may test w1 * x_i + w2 * x_j
    search: stages.SearchInfo | None = None  # how a searched tree's restart was chosen

    @property
    def label(self) -> str:
        """``distilled``, ``refined``, ``searched``, with ``, relational`` where it is."""
        return f"{self.stage}, relational" if self.relational else self.stage

    @property
    def relational_tests(self) -> int:
        return int(self.bt.relational_count)

    @property
    def bt_method(self) -> str:
        return stages.smallest_bt(self.bts)

    @property
    def bt(self) -> Any:
        return self.bts[self.bt_method]

    @property
    def bt_nodes(self) -> int:
        return int(self.bt.node_count)

    @property
    def leaves(self) -> int:
        return stages.leaves_of(self.tree)

    def row(self) -> dict[str, Any]:
        return {"leaf_limit": self.leaf_limit, "stage": self.stage, "leaves": self.leaves,
                "relational": self.relational, "relational_tests": self.relational_tests,
                "bt_nodes": self.bt_nodes, "bt_method": self.bt_method,
                **{f"nodes_{m}": bt.node_count for m, bt in self.bts.items()},
                "mean_return": self.mean_return, "retention_norm": self.retention}


class Deadline:
    """A wall-clock budget from now (``None``: no limit)."""

    def __init__(self, seconds: float | None, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.seconds, self.clock = seconds, clock
        self.start = clock()

    def passed(self) -> bool:
        return self.seconds is not None and self.clock() - self.start >= self.seconds

    def elapsed(self) -> float:
        return self.clock() - self.start


@dataclass(frozen=True)
class Settings:
    """What the ladder may do: the target, the rungs, restarts and the budgets' scale."""

    keep: float
    rungs: tuple[int, ...]
    seed: int = 0
    relational: bool = True
    restarts: int = 3
    n_jobs: int = 1
    scale: float = 1.0  # of every stage's episode budget
    refine_episodes: int | None = None  # per tree, where given (else the scaled budget)
    max_nodes: int | None = None  # the recommended BT's bound
    search: bool = True
    full: bool = False  # every rung and every step, whatever kept the target (benchmarks)
    env_modules: tuple[str, ...] = ()


@dataclass
class Ladder:
    """What the ladder did: the candidates in the order made, and why it ended."""

    candidates: list[Candidate] = field(default_factory=list)
    stopped: str | None = None  # "time", "interrupted" or the callback's reason; None: done
    steps: list[str] = field(default_factory=list)  # the steps done, in order
    skipped: list[str] = field(default_factory=list)  # the steps left undone by a stop
    notes: list[str] = field(default_factory=list)


class Stopped(Exception):
    """Raised between steps when the deadline passed or the callback asked to stop."""


def eligible(c: Candidate, settings: Settings) -> bool:
    return settings.max_nodes is None or c.bt_nodes <= settings.max_nodes


def keeps(c: Candidate, settings: Settings) -> bool:
    return eligible(c, settings) and c.retention >= 100 * settings.keep


def learners_of(agent: Agent, relational: bool) -> tuple[str, ...]:
    """``box`` on a Box task; ``axis`` then ``relational`` (two features or more) otherwise."""
    if agent.continuous:
        return ("box",)
    return ("axis", "relational") if relational and agent.task.n_features >= 2 else ("axis",)


def run_ladder(cfg: Config, agent: Agent, settings: Settings, *, agent_mean: float,
               random_mean: float, deadline: Deadline | None = None,
               on_step: Callable[[Ladder, str], str | None] | None = None) -> Ladder:
    """Climb the ladder; ``agent_mean``/``random_mean`` are the choice episodes' baselines.
    ``on_step(ladder, next_step)`` runs before every step; a string it returns stops the
    ladder with that reason."""
    deadline = deadline or Deadline(None)
    out = Ladder()
    learners = learners_of(agent, settings.relational)
    choice = stages.held_out(cfg.final_episodes, 0)
    sources: dict[tuple[int, str], list[Any]] = {}

    def step(name: str, make: Callable[[], Any], leaves: int, stage: str, learner: str,
             info: Any = None) -> Any:
        if deadline.passed():
            raise Stopped("time")
        reason = on_step(out, name) if on_step is not None else None
        if reason:
            raise Stopped(reason)
        made = make()
        tree, info = made if isinstance(made, tuple) else (made, info)
        bts = stages.synthesise(cfg, agent, tree, settings.seed)
        ret = stages.measure(cfg, agent, tree, bts, choice)
        out.candidates.append(Candidate(
            leaves, stage, tree, bts, ret.mean, ret.std,
            _retention(ret.mean, agent_mean, random_mean), learner == "relational", info))
        out.steps.append(name)
        return tree

    plan = _plan(settings, learners, agent.continuous)
    try:
        found = None
        for leaves in settings.rungs:
            for learner in learners:
                tag = f"{learner} at {leaves} leaves"
                tree = step(f"distil {tag}", partial(stages.distil, cfg, agent, leaves,
                                                     settings.seed, learner),
                            leaves, "distilled", learner)
                refined = step(f"refine {tag}", partial(
                    stages.refine, cfg, agent, tree, settings.seed, settings.scale,
                    settings.refine_episodes), leaves, "refined", learner)
                sources[leaves, learner] = _distinct([refined, tree])
            if _kept_at(out, leaves, settings) and not settings.full:
                found = leaves
                break
        if settings.search and not agent.continuous:
            for leaves in settings.rungs:
                if found is not None and leaves >= found and not settings.full:
                    break
                if (leaves, learners[0]) not in sources:
                    break  # imitation stopped below this rung
                if _kept_at(out, leaves, settings) and not settings.full:
                    continue
                for learner in learners:
                    step(f"search {learner} at {leaves} leaves", partial(
                        stages.search, cfg, agent, sources[leaves, "axis"], leaves,
                        settings.seed, restarts=settings.restarts,
                        relational=learner == "relational", scale=settings.scale,
                        n_jobs=settings.n_jobs, env_modules=settings.env_modules),
                         leaves, "searched", learner)
                if _kept_at(out, leaves, settings) and not settings.full:
                    break
        elif agent.continuous:
            out.notes.append("the structure search is for discrete actions: a Box task's "
                             "trees are distilled and refined (commands and thresholds)")
    except Stopped as stop:
        out.stopped = str(stop)
    except STOP_SIGNALS as err:  # Ctrl-C or SIGTERM inside a step: that step is not cached
        out.stopped = stop_reason(err)
    out.skipped = [s for s in plan if s not in out.steps] if out.stopped else []
    return out


def _retention(mean: float, agent_mean: float, random_mean: float) -> float:
    """Random-normalised retention (%); NaN where the agent is no better than random (the
    report says so instead of dividing by nothing)."""
    if agent_mean - random_mean <= 1e-9:
        return float("nan")
    return retention_norm(mean, agent_mean, random_mean)


def _kept_at(ladder: Ladder, leaves: int, settings: Settings) -> bool:
    return any(c.leaf_limit == leaves and keeps(c, settings) for c in ladder.candidates)


def _distinct(trees: list[Any]) -> list[Any]:
    seen: dict[str, Any] = {}
    for tree in trees:
        seen.setdefault(stages.tree_key(tree), tree)
    return list(seen.values())


def _plan(settings: Settings, learners: tuple[str, ...], continuous: bool) -> list[str]:
    """Every step the ladder could take, in order (what a stop leaves undone)."""
    names = [f"{verb} {learner} at {leaves} leaves" for leaves in settings.rungs
             for learner in learners for verb in ("distil", "refine")]
    if settings.search and not continuous:
        names += [f"search {learner} at {leaves} leaves" for leaves in settings.rungs
                  for learner in learners]
    return names
