"""The registry of tasks: the only place environment ids appear.

A :class:`Task` names an environment's features and actions, maps raw observations to the
feature vectors the trees see, and carries a box of plausible feature values used to sample
random states when testing that a BT decides exactly as its tree. Users can add their own task
with :func:`register_task`, or bring their own environment: :func:`import_env_module` imports a
module that registers gymnasium environments (and, optionally, tasks), and :func:`resolve_task`
accepts gymnasium's ``module:EnvId`` form.
"""

from __future__ import annotations

import csv
import difflib
import importlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from ibt.paths import DATA_DIR


@dataclass(frozen=True)
class Task:
    """One environment as Imitation-BT sees it."""

    name: str
    gym_id: str
    feature_names: tuple[str, ...]
    action_names: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    kwargs: dict[str, Any] = field(default_factory=dict)
    discrete_state: bool = False  # the observation is one integer (the state index)
    integer_features: bool = False  # every feature takes integer values only
    setup_module: str | None = None  # imported before gym.make (registers the env)
    max_episode_steps: int | None = None
    value_labels: tuple[tuple[int, tuple[str, ...]], ...] = ()  # categorical feature labels

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    @property
    def n_actions(self) -> int:
        return len(self.action_names)

    def make_env(self, **overrides: Any) -> gym.Env:
        """A fresh environment (kwargs of the registry, updated by ``overrides``)."""
        if self.setup_module:
            __import__(self.setup_module)
        kwargs = {**self.kwargs, **overrides}
        # gymnasium's passive checker only warns, once per env; skipping it saves a wrapper
        # call on every step of every rollout
        kwargs.setdefault("disable_env_checker", True)
        if self.max_episode_steps is not None:
            kwargs.setdefault("max_episode_steps", self.max_episode_steps)
        return gym.make(self.gym_id, **kwargs)

    @property
    def render_driver(self) -> str | None:
        """The SDL video driver this task's ``rgb_array`` frames need (None: any)."""
        return RENDER_DRIVERS.get(self.setup_module or "")

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
        space = _observation_space(self)
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

    def random_return(self) -> float:
        """Mean return of the uniform random policy (committed in data/experts/random.csv)."""
        path = DATA_DIR / "experts" / "random.csv"
        if path.exists():
            with path.open() as fh:
                for row in csv.DictReader(fh):
                    if row["task"] == self.name:
                        return float(row["mean_return"])
        raise LookupError(f"no random-policy return for {self.name} in {path}; "
                          f"run `python -m ibt random-baselines {self.name}`")


#: SDL video drivers that some renderers need: highway-env draws all-black ``rgb_array`` frames
#: under ``dummy`` (what the Makefile exports) and real ones under ``offscreen``
RENDER_DRIVERS: dict[str, str] = {"highway_env": "offscreen"}


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


_SPACES: dict[str, Any] = {}


def _observation_space(task: Task):
    if task.name not in _SPACES:
        env = task.make_env()
        try:
            _SPACES[task.name] = env.observation_space
        finally:
            env.close()
    return _SPACES[task.name]


TASKS: dict[str, Task] = {}


def register_task(task: Task) -> Task:
    """Add (or replace) a task in the registry; returns it."""
    TASKS[task.name] = task
    return task


def get_task(name: str | Task) -> Task:
    """Look a task up by name; unknown names get the closest known ones in the message."""
    if isinstance(name, Task):
        return name
    try:
        return TASKS[name]
    except KeyError:
        close = difflib.get_close_matches(name, TASKS, n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        raise KeyError(f"unknown task {name!r}.{hint} Known tasks: {', '.join(TASKS)}; "
                       "bring your own environment with --env-module MODULE (command line) or "
                       "ibt.tasks.catalogue.register_task (Python)") from None


def _highway_features() -> tuple[str, ...]:
    names = []
    for vehicle in ["ego", "v1", "v2", "v3", "v4"]:
        names += [f"{vehicle}_{k}" for k in ("presence", "x", "y", "vx", "vy")]
    return tuple(names)


register_task(Task(
    name="CartPole-v1", gym_id="CartPole-v1",
    feature_names=("cart_position", "cart_velocity", "pole_angle", "pole_angular_velocity"),
    action_names=("push_left", "push_right"),
    low=(-2.4, -3.0, -0.21, -3.5), high=(2.4, 3.0, 0.21, 3.5),
))
register_task(Task(
    name="Acrobot-v1", gym_id="Acrobot-v1",
    feature_names=("cos_theta1", "sin_theta1", "cos_theta2", "sin_theta2",
                   "theta1_velocity", "theta2_velocity"),
    action_names=("torque_neg", "torque_zero", "torque_pos"),
    low=(-1, -1, -1, -1, -12.6, -28.3), high=(1, 1, 1, 1, 12.6, 28.3),
))
register_task(Task(
    name="MountainCar-v0", gym_id="MountainCar-v0",
    feature_names=("position", "velocity"),
    action_names=("left", "no_push", "right"),
    low=(-1.2, -0.07), high=(0.6, 0.07),
))
register_task(Task(
    name="LunarLander-v3", gym_id="LunarLander-v3",
    feature_names=("x", "y", "vx", "vy", "angle", "angular_velocity",
                   "left_leg_contact", "right_leg_contact"),
    action_names=("noop", "fire_left", "fire_main", "fire_right"),
    low=(-1.5, -0.2, -2.0, -2.0, -3.14, -5.0, 0, 0), high=(1.5, 1.6, 2.0, 0.6, 3.14, 5.0, 1, 1),
    setup_module="Box2D",
))
register_task(Task(
    name="CliffWalking-v1", gym_id="CliffWalking-v1",
    feature_names=("state",), action_names=("up", "right", "down", "left"),
    low=(0,), high=(47,), discrete_state=True, integer_features=True, max_episode_steps=100,
))
register_task(Task(
    name="FrozenLake-v1", gym_id="FrozenLake-v1", kwargs={"map_name": "4x4", "is_slippery": False},
    feature_names=("state",), action_names=("left", "down", "right", "up"),
    low=(0,), high=(15,), discrete_state=True, integer_features=True,
))
register_task(Task(
    name="highway-fast-v0", gym_id="highway-fast-v0",
    feature_names=_highway_features(),
    action_names=("lane_left", "idle", "lane_right", "faster", "slower"),
    low=(0, -1, -1, -1, -1) * 5, high=(1, 1, 1, 1, 1) * 5,
    setup_module="highway_env",
))


def _package_delivery() -> Task:
    from ibt.envs import package_delivery as pd

    space = pd.PackageDeliveryEnv().observation_space
    assert isinstance(space, gym.spaces.MultiDiscrete)
    high = tuple(float(n - 1) for n in space.nvec)
    return Task(
        name="PackageDelivery-v0", gym_id="PackageDelivery-v0",
        feature_names=tuple(pd.FEATURE_NAMES), action_names=tuple(pd.ACTION_NAMES),
        low=(0.0,) * len(high), high=high, setup_module="ibt.envs", integer_features=True,
        value_labels=tuple((pd.FEATURE_NAMES.index(f), tuple(v))
                           for f, v in pd.FEATURE_VALUES.items()),
    )


try:  # the package-delivery domain is ours; register it when its module is present
    register_task(_package_delivery())
except ImportError:  # pragma: no cover - only while the module is being written
    pass


def task_from_env(gym_id: str, **kwargs: Any) -> Task:
    """A task for any gymnasium env with a flat Box (or Discrete) observation and discrete actions.

    Features are named ``x0, x1, ...`` and actions ``a0, a1, ...``; register a :class:`Task`
    yourself for readable names. Raises ``KeyError`` for an unknown env id and ``ValueError``
    for spaces Imitation-BT cannot handle.
    """
    if gym_id in TASKS:
        return TASKS[gym_id]
    try:
        env = gym.make(gym_id, **kwargs)
    except gym.error.Error as err:
        raise KeyError(f"unknown environment id {gym_id!r} ({err}); registered tasks: "
                       f"{', '.join(TASKS)}") from None
    except Exception as err:  # the environment's own constructor failed
        raise ValueError(f"making the environment {gym_id!r} failed ({type(err).__name__}: "
                         f"{err}); fix its constructor or its registered kwargs") from None
    obs_space, act_space = env.observation_space, env.action_space
    env.close()
    if not isinstance(act_space, gym.spaces.Discrete):
        raise ValueError(f"{gym_id} has actions {act_space}; Imitation-BT needs a Discrete "
                         "action space")
    actions = tuple(f"a{i}" for i in range(int(act_space.n)))
    if isinstance(obs_space, gym.spaces.Discrete):
        return Task(gym_id, gym_id, ("state",), actions, (0,), (int(obs_space.n) - 1,),
                    kwargs=kwargs, discrete_state=True, integer_features=True)
    if not isinstance(obs_space, gym.spaces.Box):
        raise ValueError(f"{gym_id} observes {obs_space}; Imitation-BT needs a Box or Discrete "
                         "observation space")
    low = np.clip(obs_space.low.reshape(-1), -10, 10)
    high = np.clip(obs_space.high.reshape(-1), -10, 10)
    names = tuple(f"x{i}" for i in range(len(low)))
    return Task(gym_id, gym_id, names, actions, tuple(map(float, low)), tuple(map(float, high)),
                kwargs=kwargs)


def import_env_module(name: str) -> None:
    """Import a user's module that registers gymnasium environments (and, optionally, tasks
    with :func:`register_task`); ``LookupError`` says why it could not be imported."""
    try:
        importlib.import_module(name)
    except ModuleNotFoundError as err:
        if err.name is not None and (name + ".").startswith(err.name + "."):
            raise LookupError(f"cannot import the environment module {name!r}: no module named "
                              f"{err.name!r}; put the folder that holds it on PYTHONPATH or "
                              "install it") from None
        raise LookupError(f"the environment module {name!r} failed to import: {err}") from None
    except Exception as err:  # the module's own code failed
        raise LookupError(f"the environment module {name!r} failed to import "
                          f"({type(err).__name__}: {err}); fix the module") from None


def resolve_task(name: str) -> Task:
    """A registered task, else one built from a gymnasium env id (:func:`task_from_env`).

    Gymnasium's ``module:EnvId`` form imports ``module`` first (it registers ``EnvId``); the
    task is then ``EnvId``, and its environments import ``module`` wherever they are made.
    """
    module = None
    if ":" in name:
        module, _, name = name.partition(":")
        if not module or not name:
            raise LookupError(f"{module}:{name} is not of the form MODULE:EnvId")
        import_env_module(module)
    if name in TASKS:
        return TASKS[name]
    if name in gym.registry:
        task = task_from_env(name)
        return replace(task, setup_module=module) if module and not task.setup_module else task
    return get_task(name)  # raises with the closest registered names


def task_names() -> list[str]:
    return list(TASKS)


def data_path(*parts: str) -> Path:
    return DATA_DIR.joinpath(*parts)
