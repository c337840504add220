"""Episodes of any policy, returns and retention.

:func:`rollout` runs whole episodes, several environments side by side so that every policy
query is one batch; each episode starts from ``env.reset(seed=s)`` with its own seed, so a set
of seeds fixes the episodes exactly. The seed ranges below keep training, best-tree selection
and final evaluation episodes disjoint.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ibt.tasks.task import Task

FINAL_SEED_BASE = 1_000_000  # final evaluation: the same episodes for every method and expert
SELECTION_SEED_BASE = 2_000_000  # best-tree selection (held out from training and final)
TRAIN_SEED_BASE = 3_000_000  # distillation rollouts
REFINE_SEED_BASE = 10_000_000  # refinement by return (1,000,000 per run seed)
REFINE_SELECTION_OFFSET = 5_000  # refinement's held-out choice: selection seeds 5,000 and up


def final_seeds(n: int) -> list[int]:
    """The fixed episode seeds of final evaluations."""
    return [FINAL_SEED_BASE + i for i in range(n)]


def selection_seeds(n: int, run_seed: int, offset: int = 0) -> list[int]:
    """Held-out episodes for choosing among candidates (``offset`` keeps uses apart)."""
    if not (0 <= offset and offset + n <= 10_000):
        raise ValueError(f"selection seeds {offset}..{offset + n} leave the run's block of 10,000")
    return [SELECTION_SEED_BASE + 10_000 * run_seed + offset + i for i in range(n)]


@dataclass
class Rollout:
    """What a batch of episodes produced, in seed order."""

    returns: np.ndarray
    lengths: np.ndarray
    final_infos: list[dict[str, Any]]
    terminated: np.ndarray  # True where the episode ended in a terminal state (not a time limit)
    obs: list[np.ndarray] = field(default_factory=list)  # per step batch, when collected

    @property
    def mean(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std(self) -> float:
        return float(np.std(self.returns))


ActFn = Callable[[np.ndarray], np.ndarray]
IndexedActFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (obs, episode indices)


def rollout(task: Task, act: ActFn | IndexedActFn, seeds: Sequence[int], *, n_envs: int = 16,
            collect: bool = False, budget: int | None = None,
            env_kwargs: dict[str, Any] | None = None,
            on_step: Callable[[np.ndarray, np.ndarray], None] | None = None,
            indexed: bool = False) -> Rollout:
    """Run one whole episode per seed with ``act`` (a batch of raw observations -> actions).

    ``budget``: stop *starting* episodes once this many steps have been taken (running episodes
    always finish; unused seeds are dropped). ``collect``: keep every observation batch.
    ``on_step(obs, actions)`` sees each batch before it is stepped. ``indexed``: call
    ``act(obs, episodes)``, where ``episodes`` are the positions in ``seeds`` of the episodes
    the rows belong to (how one batch runs several policies side by side, see
    ``ibt.refine.by_return``).
    """
    seeds = list(seeds)
    box = task.continuous  # actions are vectors (rows of ``act``'s answer), not indices
    n_slots = max(1, min(n_envs, len(seeds)))
    envs = [task.make_env(**(env_kwargs or {})) for _ in range(n_slots)]
    returns = np.zeros(len(seeds))
    lengths = np.zeros(len(seeds), dtype=np.int64)
    infos: list[dict[str, Any]] = [{} for _ in seeds]
    terminal = np.zeros(len(seeds), dtype=bool)
    collected: list[np.ndarray] = []
    slot_episode = [-1] * n_slots
    slot_obs: list[Any] = [None] * n_slots
    next_episode = 0
    steps = 0

    def start(slot: int) -> None:
        nonlocal next_episode
        if next_episode >= len(seeds) or (budget is not None and steps >= budget):
            slot_episode[slot] = -1
            return
        slot_episode[slot] = next_episode
        slot_obs[slot], _ = envs[slot].reset(seed=int(seeds[next_episode]))
        next_episode += 1

    for slot in range(n_slots):
        start(slot)
    try:
        while True:
            active = [s for s in range(n_slots) if slot_episode[s] >= 0]
            if not active:
                break
            obs = np.stack([np.asarray(slot_obs[s]) for s in active])
            if indexed:
                episodes = np.array([slot_episode[s] for s in active])
                actions = np.asarray(act(obs, episodes))  # type: ignore[call-arg]
            else:
                actions = np.asarray(act(obs))  # type: ignore[call-arg]
            if on_step is not None:
                on_step(obs, actions)
            if collect:
                collected.append(obs)
            steps += len(active)
            for s, action in zip(active, actions, strict=True):
                ep = slot_episode[s]
                slot_obs[s], reward, terminated, truncated, info = envs[s].step(
                    np.asarray(action, dtype=np.float32) if box else int(action))
                returns[ep] += float(reward)
                lengths[ep] += 1
                if terminated or truncated:
                    infos[ep] = dict(info)
                    terminal[ep] = bool(terminated)
                    start(s)
    finally:
        for env in envs:
            env.close()
    used = next_episode
    return Rollout(returns[:used], lengths[:used], infos[:used], terminal[:used], collected)


def _rate(values: Any) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


#: How each outcome rate of :data:`ibt.tasks.settings.METRICS` is read off a rollout.
METRIC_FUNCTIONS: dict[str, tuple[str, Callable[[Rollout], float]]] = {
    "success_if_positive": ("success_rate", lambda r: _rate(r.returns > 0)),
    "success_if_terminated": ("success_rate", lambda r: _rate(r.terminated)),
    "collision_rate": ("collision_rate",
                       lambda r: _rate([bool(i.get("crashed")) for i in r.final_infos])),
    "battery_failure_rate": ("battery_failure_rate",
                             lambda r: _rate([bool(i.get("battery_failure"))
                                              for i in r.final_infos])),
    "delivered": ("delivered", lambda r: _rate([i.get("delivered_heavy", 0)
                                                + i.get("delivered_light", 0)
                                                for i in r.final_infos])),
}


def episode_metrics(task: Task, result: Rollout) -> dict[str, float]:
    """The task's outcome rates beside the return (``Task.metrics``: success, collisions,
    battery failures, deliveries)."""
    out: dict[str, float] = {}
    for metric in task.metrics:
        try:
            column, measure = METRIC_FUNCTIONS[metric]
        except KeyError:
            raise ValueError(f"{task.name} asks for an unknown metric {metric!r}; known: "
                             f"{', '.join(METRIC_FUNCTIONS)}") from None
        out[column] = measure(result)
    return out


def retention_raw(mean_return: float, expert_return: float) -> float:
    """The paper's retention: mean return as a percentage of the expert's."""
    return 100.0 * mean_return / expert_return


def retention_norm(mean_return: float, expert_return: float, random_return: float) -> float:
    """Random-normalised retention: 0 = random policy, 100 = expert (meaningful for negative
    returns, where the raw percentage is not)."""
    return 100.0 * (mean_return - random_return) / (expert_return - random_return)
