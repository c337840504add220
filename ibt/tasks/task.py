"""One environment as Imitation-BT sees it: a frozen, hashable :class:`Task`.

A task names an environment's features and actions, maps raw observations to the feature
vectors the trees see, carries a box of plausible feature values (to sample random states when
testing that a BT decides exactly as its tree), and every per-task setting of the pipeline
(:mod:`ibt.tasks.settings`): the distillation budget, the experts' hyperparameters and quality
bar, outcome metrics, seeds, the refinement budget, the animation clip and the front target.

A task is resolved from its name once, at a boundary (CLI, notebook, grid cell creation), and
the object is passed down whole, also into worker processes: it is hashable and picklable, and
an edited copy (``dataclasses.replace``) is used as given, never swapped for the registry's.
"""

from __future__ import annotations

import csv
import functools
import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ibt.paths import DATA_DIR
from ibt.tasks.settings import (
    Clip,
    EvolveConfig,
    FrontTarget,
    Hyperparams,
    QualityBar,
    RefineConfig,
    TaskBudget,
)

if TYPE_CHECKING:
    import gymnasium as gym

CLAIM_GROUPS = ("simple", "stochastic")  #: the paper's two groups of tasks in its claims


@dataclass(frozen=True)
class Task:
    """One environment and every per-task fact of the pipeline (one catalogue entry)."""

    name: str
    gym_id: str
    feature_names: tuple[str, ...]
    action_names: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    # gymnasium.make keyword arguments; a dict is accepted and stored as sorted pairs
    kwargs: tuple[tuple[str, Any], ...] | Mapping[str, Any] = ()
    discrete_state: bool = False  # the observation is one integer (the state index)
    integer_features: bool = False  # every feature takes integer values only
    setup_module: str | None = None  # imported before gym.make (registers the env)
    max_episode_steps: int | None = None
    value_labels: tuple[tuple[int, tuple[str, ...]], ...] = ()  # categorical feature labels
    # --- per-task settings of the pipeline (defaults suit a user's own task) ---
    budget: TaskBudget = field(default_factory=TaskBudget)
    experts: tuple[tuple[str, Hyperparams], ...] = ()  # (algo, hyperparameters) we train
    bar: QualityBar = field(default_factory=QualityBar)
    metrics: tuple[str, ...] = ()  # names from ibt.tasks.settings.METRICS
    paper_seeds: int = 5  # seeds per cell of the paper grid
    refine: RefineConfig = field(default_factory=RefineConfig)
    refine_sources: int = 1  # how many source trees Imitation-BT+ refines
    evolve: EvolveConfig | None = None  # Imitation-BT+S's structure-search budget
    clip: Clip | None = None  # filmed by `make animations`
    front_target: FrontTarget | None = None
    claim_group: str | None = None  # "simple" or "stochastic" (the paper's claims)
    render_driver: str | None = None  # SDL video driver its rgb_array frames need
    scripted_policy: str | None = None  # "module:function", the bar's reference policy
    # --- continuous actions (a gymnasium Box): empty for a task with discrete actions ---
    # the Box's bounds, one per command dimension (``action_names`` then names the dimensions)
    action_low: tuple[float, ...] = ()
    action_high: tuple[float, ...] = ()
    action_units: tuple[str, ...] = ()  # one unit per dimension ("" where none), for readers
    # --- where episodes are cut when this run says so (not the catalogue's) ---
    # --max-episode-steps, or the default cap of an environment that sets no limit: overrides
    # the environment's own limit and is part of every cache key (:attr:`key`)
    episode_cap: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.kwargs, Mapping):
            object.__setattr__(self, "kwargs", tuple(sorted(self.kwargs.items())))
        for name in ("feature_names", "action_names", "low", "high", "action_low",
                     "action_high", "action_units"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.action_low or self.action_high:
            n = len(self.action_names)
            if not (len(self.action_low) == len(self.action_high) == n) or any(
                    not lo < hi for lo, hi in zip(self.action_low, self.action_high,
                                                  strict=True)):
                raise ValueError(f"{self.name}: action_low and action_high must give one "
                                 f"interval low < high per action dimension ({n})")
            if self.action_units and len(self.action_units) != n:
                raise ValueError(f"{self.name}: action_units must name one unit per action "
                                 f"dimension ({n})")
        if self.episode_cap is not None and not (isinstance(self.episode_cap, int)
                                                 and self.episode_cap >= 1):
            raise ValueError(f"{self.name}: episode_cap must be a whole number of steps >= 1, "
                             f"got {self.episode_cap!r}")
        if self.claim_group is not None and self.claim_group not in CLAIM_GROUPS:
            raise ValueError(f"claim_group must be one of {CLAIM_GROUPS}, got "
                             f"{self.claim_group!r}")

    @property
    def key(self) -> str:
        """The task in cache keys: its name, with the episode cap where this run sets one (a
        cut episode is another computation)."""
        if self.episode_cap is None:
            return self.name
        return f"{self.name} (episodes cut at {self.episode_cap} steps)"

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    @property
    def n_actions(self) -> int:
        """The number of discrete actions, or of action dimensions of a Box task."""
        return len(self.action_names)

    @property
    def continuous(self) -> bool:
        """Whether the task acts in a Box (its actions are vectors, not indices)."""
        return bool(self.action_low)

    def check_action(self, action: np.ndarray) -> np.ndarray:
        """A Box task's action vectors ``(n, dims)`` as float32, checked: finite and inside
        the Box; ``ValueError`` names the first one outside."""
        a = np.asarray(action, dtype=np.float64).reshape(-1, self.n_actions)
        low, high = np.asarray(self.action_low), np.asarray(self.action_high)
        bad = ~np.isfinite(a).all(axis=1) | (a < low).any(axis=1) | (a > high).any(axis=1)
        if bad.any():
            raise ValueError(f"action {a[bad][0].tolist()} is outside {self.name}'s action "
                             f"space [{list(self.action_low)}, {list(self.action_high)}]")
        return a.astype(np.float32)

    @property
    def env_kwargs(self) -> dict[str, Any]:
        """The gymnasium.make keyword arguments as a dict."""
        return dict(self.kwargs)

    def hyperparams(self, algo: str) -> Hyperparams:
        """How this task's ``algo`` expert is trained; ``KeyError`` names the fix."""
        try:
            return dict(self.experts)[algo]
        except KeyError:
            raise KeyError(f"no hyperparameters for ({self.name}, {algo}); add ({algo!r}, "
                           "Hyperparams(...)) to the task's `experts` in its catalogue entry "
                           "(ibt/tasks/builtin.py)") from None

    def make_env(self, **overrides: Any) -> gym.Env:
        """A fresh environment (the entry's kwargs, updated by ``overrides``)."""
        import gymnasium as gym

        if self.setup_module:
            __import__(self.setup_module)
        kwargs = {**self.env_kwargs, **overrides}
        # gymnasium's passive checker only warns, once per env; skipping it saves a wrapper
        # call on every step of every rollout
        kwargs.setdefault("disable_env_checker", True)
        if self.episode_cap is not None:
            kwargs["max_episode_steps"] = self.episode_cap
        elif self.max_episode_steps is not None:
            kwargs.setdefault("max_episode_steps", self.max_episode_steps)
        return gym.make(self.gym_id, **kwargs)

    def render_frame(self, seed: int = 0, steps: int = 5) -> np.ndarray:
        """An RGB frame a few random steps after a seeded reset (for figures)."""
        with sdl_video_driver(self.render_driver):
            env = self.make_env(render_mode="rgb_array")
            try:
                env.reset(seed=seed)
                env.action_space.seed(seed)
                for _ in range(steps):
                    _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                    if terminated or truncated:
                        env.reset(seed=seed)
                return np.asarray(env.render())
            finally:
                env.close()

    def features(self, obs: np.ndarray) -> np.ndarray:
        """Raw observations (a batch) -> float32 feature matrix ``(n, n_features)``."""
        obs = np.asarray(obs)
        if self.discrete_state:
            return obs.reshape(-1, 1).astype(np.float32)
        return obs.reshape(len(obs), -1).astype(np.float32)

    def observations(self, features: np.ndarray) -> np.ndarray:
        """Feature rows -> the raw observations an expert takes (inverse of :meth:`features`)."""
        space = observation_space(self)
        x = np.asarray(features)
        if self.discrete_state:
            return x[:, 0].astype(space.dtype)
        return x.reshape(len(x), *space.shape).astype(space.dtype)

    def sample_features(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` random feature vectors from the task's box (integers for discrete states)."""
        low, high = np.asarray(self.low), np.asarray(self.high)
        if self.discrete_state or self.integer_features:
            return rng.integers(low, high + 1, size=(n, len(low))).astype(np.float32)
        return rng.uniform(low, high, size=(n, len(low))).astype(np.float32)

    def random_return(self, experts_dir: Path | None = None) -> float:
        """Mean return of the uniform random policy (``random.csv`` of the experts folder,
        committed in data/experts/random.csv)."""
        path = (experts_dir or DATA_DIR / "experts") / "random.csv"
        if path.exists():
            with path.open() as fh:
                for row in csv.DictReader(fh):
                    if row["task"] == self.name:
                        return float(row["mean_return"])
        raise LookupError(f"no random-policy return for {self.name} in {path}; "
                          f"run `python -m ibt random-baselines {self.name}`")


@functools.cache
def observation_space(task: Task) -> Any:
    """The task's observation space (one environment made per task object and process)."""
    env = task.make_env()
    try:
        return env.observation_space
    finally:
        env.close()


@contextmanager
def sdl_video_driver(name: str | None) -> Iterator[None]:
    """pygame renders with SDL's video driver ``name`` inside the block (None: unchanged);
    the driver before it is restored afterwards."""
    before = os.environ.get("SDL_VIDEODRIVER")
    if name is None or before == name:
        yield
        return
    import pygame

    pygame.display.quit()  # the driver is chosen when the display starts
    os.environ["SDL_VIDEODRIVER"] = name
    try:
        yield
    finally:
        pygame.display.quit()
        if before is None:
            os.environ.pop("SDL_VIDEODRIVER", None)
        else:
            os.environ["SDL_VIDEODRIVER"] = before
