"""Episodes of any policy, returns and retention.

:func:`rollout` runs whole episodes, several environments side by side so that every policy
query is one batch; each episode starts from ``env.reset(seed=s)`` with its own seed, so a set
of seeds fixes the episodes exactly. The seed ranges below keep training, best-tree selection
and final evaluation episodes disjoint.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ibt.tasks.builtin import BUILTIN, CONTINUOUS
from ibt.tasks.settings import DEFAULT_MAX_EPISODE_STEPS
from ibt.tasks.task import Task

FINAL_SEED_BASE = 1_000_000  # final evaluation: the same episodes for every method and expert
SELECTION_SEED_BASE = 2_000_000  # best-tree selection (held out from training and final)
TRAIN_SEED_BASE = 3_000_000  # distillation rollouts
REFINE_SEED_BASE = 10_000_000  # refinement by return (1,000,000 per run seed)
REFINE_SELECTION_OFFSET = 5_000  # refinement's held-out choice: selection seeds 5,000 and up
SELECTION_BLOCK = 10_000  # each run seed's block of selection seeds


def final_seeds(n: int) -> list[int]:
    """The fixed episode seeds of final evaluations."""
    return [FINAL_SEED_BASE + i for i in range(n)]


def selection_seeds(n: int, run_seed: int, offset: int = 0) -> list[int]:
    """Held-out episodes for choosing among candidates (``offset`` keeps uses apart)."""
    if not (0 <= offset and offset + n <= SELECTION_BLOCK):
        raise ValueError(f"selection seeds {offset}..{offset + n} leave the run's block of "
                         f"{SELECTION_BLOCK:,}")
    return [SELECTION_SEED_BASE + SELECTION_BLOCK * run_seed + offset + i for i in range(n)]


class ReturnStats:
    """The mean and standard deviation of a record's episode ``returns`` (its one home: a
    :class:`Rollout`, a stage's :class:`ibt.engine.measure.Returns`)."""

    returns: Any  # an array or a list of episode returns

    @property
    def mean(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std(self) -> float:
        return float(np.std(self.returns))


@dataclass
class Rollout(ReturnStats):
    """What a batch of episodes produced, in seed order."""

    returns: np.ndarray
    lengths: np.ndarray
    final_infos: list[dict[str, Any]]
    terminated: np.ndarray  # True where the episode ended in a terminal state (not a time limit)
    obs: list[np.ndarray] = field(default_factory=list)  # per step batch, when collected


ActFn = Callable[[np.ndarray], np.ndarray]
IndexedActFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (obs, episode indices)


_ONE_LINE = 160  # characters of an environment's own error message kept in ours


class EnvError(RuntimeError):
    """The environment misbehaved: its ``reset``/``step`` raised, or returned a non-finite
    reward or an observation that is not finite or not of its observation space's shape. The
    message is one line: the environment, the call, the episode's seed and step, the fault and
    the fix (the command line prints it and exits with 2)."""


def _fault(task: Task, call: str, seed: int, step: int, problem: str, fix: str) -> EnvError:
    where = "reset" if call == "reset" else f"step {step}"
    return EnvError(f"the environment {task.gym_id} failed in {call}() ({where} of the episode "
                    f"with seed {seed}): {problem}; {fix}")


def _raised(err: BaseException) -> str:
    text = " ".join(str(err).split())
    text = text if len(text) <= _ONE_LINE else text[:_ONE_LINE - 3] + "..."
    return f"it raised {type(err).__name__}" + (f": {text}" if text else "")


def _bad_obs(task: Task, obs: Any, shape: tuple[int, ...] | None) -> str | None:
    """Why ``obs`` (one observation) is unusable, or None."""
    try:
        array = np.asarray(obs)
    except Exception as err:  # a ragged or strange object
        return f"it returned an observation numpy cannot read ({type(err).__name__})"
    if shape is not None and array.shape != shape:
        return (f"it returned an observation of shape {array.shape}, but its observation_space "
                f"has shape {shape}")
    if array.dtype.kind not in "biuf":
        return f"it returned an observation of dtype {array.dtype}, not numbers"
    if not np.isfinite(array).all():
        bad = np.flatnonzero(~np.isfinite(array.reshape(-1)))
        names = task.feature_names
        which = ", ".join(f"{names[i] if i < len(names) else i}={array.reshape(-1)[i]}"
                          for i in bad[:3])
        return f"it returned a non-finite observation ({which})"
    return None


#: the catalogue's own tasks: their episodes end (highway's by its own clock, with no limit set)
_BUILTIN = frozenset(t.name for t in (*BUILTIN, *CONTINUOUS))


def _capped(env: Any, task: Task) -> Any:
    """``env`` with a time limit: an environment that sets none (a user's) is cut at
    :data:`DEFAULT_MAX_EPISODE_STEPS` (with a warning), so that no rollout runs forever."""
    spec = getattr(env, "spec", None)
    if task.name in _BUILTIN or (spec is not None and spec.max_episode_steps is not None):
        return env
    import warnings

    import gymnasium as gym

    warnings.warn(f"{getattr(spec, 'id', env)} sets no max_episode_steps: its episodes are "
                  f"cut at {DEFAULT_MAX_EPISODE_STEPS:,} steps (set Task.episode_cap, or "
                  "--max-episode-steps N on the command line)", stacklevel=3)
    return gym.wrappers.TimeLimit(env, DEFAULT_MAX_EPISODE_STEPS)


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

    The environment is checked as it runs, at a cost of one test per step and one per batch:
    an exception from its ``reset``/``step``, a reward that is not a finite number (or returns
    that overflow), an observation that is not finite or not of its space's shape all raise
    :class:`EnvError`, which names the call, the episode's seed and step. An environment that
    sets no episode limit is cut at :data:`DEFAULT_MAX_EPISODE_STEPS` steps.
    """
    seeds = list(seeds)
    box = task.continuous  # actions are vectors (rows of ``act``'s answer), not indices
    n_slots = max(1, min(n_envs, len(seeds)))
    envs = [_capped(task.make_env(**(env_kwargs or {})), task) for _ in range(n_slots)]
    returns = np.zeros(len(seeds))
    lengths = np.zeros(len(seeds), dtype=np.int64)
    infos: list[dict[str, Any]] = [{} for _ in seeds]
    terminal = np.zeros(len(seeds), dtype=bool)
    collected: list[np.ndarray] = []
    slot_episode = [-1] * n_slots
    slot_obs: list[Any] = [None] * n_slots
    slot_return = [0.0] * n_slots  # the running episode's return and length, as Python numbers
    slot_length = [0] * n_slots
    space_shape = getattr(envs[0].observation_space, "shape", None)
    shape = None if space_shape is None else tuple(space_shape)
    next_episode = 0
    steps = 0
    isfinite = math.isfinite

    def start(slot: int) -> None:
        nonlocal next_episode
        if next_episode >= len(seeds) or (budget is not None and steps >= budget):
            slot_episode[slot] = -1
            return
        seed = int(seeds[next_episode])
        slot_episode[slot], slot_return[slot], slot_length[slot] = next_episode, 0.0, 0
        try:
            answer = envs[slot].reset(seed=seed)
        except Exception as err:
            raise _fault(task, "reset", seed, 0, _raised(err), "fix its reset()") from err
        try:
            slot_obs[slot], _ = answer
        except (TypeError, ValueError):
            raise _fault(task, "reset", seed, 0, "it returned no (observation, info) pair",
                         "gymnasium's reset returns (observation, info)") from None
        next_episode += 1

    def check(active: list[int]) -> np.ndarray:
        """The batch of observations, after checking it (rows are looked at only on a fault)."""
        try:
            obs = np.stack([np.asarray(slot_obs[s]) for s in active])
            if ((shape is None or obs.shape[1:] == shape) and obs.dtype.kind in "biuf"
                    and (obs.dtype.kind != "f" or np.isfinite(obs).all())):
                return obs
        except Exception:  # ragged shapes: one row is at fault, found below
            pass
        for s in active:
            problem = _bad_obs(task, slot_obs[s], shape)
            if problem is not None:
                call = "reset" if slot_length[s] == 0 else "step"
                fix = (f"make its {call}() return finite observations" if "finite" in problem
                       else f"make its {call}() return observations of its observation_space")
                raise _fault(task, call, int(seeds[slot_episode[s]]), slot_length[s], problem,
                             fix)
        raise _fault(task, "step", int(seeds[slot_episode[active[0]]]), slot_length[active[0]],
                     "its observations cannot be stacked into a batch",
                     "return numeric arrays of its observation_space")

    for slot in range(n_slots):
        start(slot)
    try:
        while True:
            active = [s for s in range(n_slots) if slot_episode[s] >= 0]
            if not active:
                break
            obs = check(active)
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
                a = np.asarray(action, dtype=np.float32) if box else int(action)
                try:
                    answer = envs[s].step(a)
                except Exception as err:
                    raise _fault(task, "step", int(seeds[slot_episode[s]]), slot_length[s] + 1,
                                 f"{_raised(err)} (action {a!r})", "fix its step()") from err
                try:
                    slot_obs[s], reward, terminated, truncated, info = answer
                    total = slot_return[s] + float(reward)
                except (TypeError, ValueError):
                    raise _fault(task, "step", int(seeds[slot_episode[s]]), slot_length[s] + 1,
                                 _bad_answer(answer), "gymnasium's step returns (observation, "
                                 "reward, terminated, truncated, info), the reward a number"
                                 ) from None
                slot_length[s] += 1
                if not isfinite(total):
                    raise _fault(task, "step", int(seeds[slot_episode[s]]), slot_length[s],
                                 *_bad_reward(reward, total))
                slot_return[s] = total
                if terminated or truncated:
                    ep = slot_episode[s]
                    returns[ep], lengths[ep] = total, slot_length[s]
                    infos[ep] = dict(info)
                    terminal[ep] = bool(terminated)
                    start(s)
    finally:
        for env in envs:
            env.close()
    used = next_episode
    return Rollout(returns[:used], lengths[:used], infos[:used], terminal[:used], collected)


def visited_features(task: Task, decide: Callable[[np.ndarray], np.ndarray],
                     seeds: Sequence[int], *, n_envs: int) -> np.ndarray:
    """The feature rows a policy (``decide``: feature rows -> actions) visits on ``seeds``, in
    the order it decided them."""
    states: list[np.ndarray] = []

    def act(obs: np.ndarray) -> np.ndarray:
        x = task.features(obs)
        states.append(x)
        return decide(x)

    rollout(task, act, seeds, n_envs=n_envs)
    return np.concatenate(states)


def _bad_answer(answer: Any) -> str:
    if not isinstance(answer, tuple) or len(answer) != 5:
        size = f"{len(answer)} values" if isinstance(answer, tuple) else type(answer).__name__
        return f"it returned {size}, not gymnasium's 5"
    return f"it returned a reward {answer[1]!r:.40} that is not a number"


def _bad_reward(reward: Any, total: float) -> tuple[str, str]:
    """The problem and the fix of a step whose reward, or the return so far, is not finite."""
    if not math.isfinite(float(reward)):
        return f"it returned the reward {float(reward)}", "return finite rewards"
    return (f"the rewards summed to {total} (this reward: {float(reward):.3g})",
            "scale the reward down so that an episode's return stays finite")


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
    returns, where the raw percentage is not). NaN where the expert's return is the random
    policy's: retention is then undefined (a share of no difference), not an error."""
    span = expert_return - random_return
    if span == 0 or not math.isfinite(span):
        return float("nan")
    return 100.0 * (mean_return - random_return) / span


def retention_norm_column(mean_return: Any, expert_return: Any, random_return: Any) -> Any:
    """:func:`retention_norm` of columns (pandas Series or arrays), NaN where undefined."""
    span = expert_return - random_return
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * (mean_return - random_return) / span
    return out.where(np.isfinite(span) & (span != 0))


def retention_margin(policy_std: float, expert_std: float, n_episodes: int,
                     expert_return: float, random_return: float) -> float:
    """Two standard errors of a random-normalised retention, in percentage points: the noise
    of ``policy - expert`` over ``n_episodes`` episodes each, on the retention's scale (NaN
    where retention is undefined). A retention above ``100 + margin`` beats the expert beyond
    noise."""
    span = abs(expert_return - random_return)
    if span == 0 or not math.isfinite(span) or n_episodes < 1:
        return float("nan")
    return 200.0 * math.sqrt((policy_std ** 2 + expert_std ** 2) / n_episodes) / span
