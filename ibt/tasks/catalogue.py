"""The task catalogue: the registry of :class:`~ibt.tasks.task.Task` entries, and the only
place a task *name* becomes a task.

The built-in entries are in :mod:`ibt.tasks.builtin`; users add their own with
:func:`register_task`, or bring their own environment: :func:`import_env_module` imports a
module that registers gymnasium environments (and, optionally, tasks), and :func:`resolve_task`
accepts gymnasium's ``module:EnvId`` form. Resolve a name once, at a boundary (the CLI, a
notebook, grid cell creation); everything below takes the :class:`Task` object.
"""

from __future__ import annotations

import difflib
import importlib
from dataclasses import replace
from typing import Any

import numpy as np

from ibt.tasks.builtin import BUILTIN, CONTINUOUS
from ibt.tasks.settings import (
    BOX_MAX_LEAF_NODES,
    DEFAULT_MAX_EPISODE_STEPS,
    DEFAULT_MAX_LEAF_NODES,
    TaskBudget,
)
from ibt.tasks.task import Task, sdl_video_driver

__all__ = ["TASKS", "Task", "TaskMismatch", "check_task", "check_user_task", "get_task",
           "import_env_module", "register_task", "resolve_task", "sdl_video_driver",
           "task_from_env", "with_episode_cap"]

TASKS: dict[str, Task] = {}
BUILTIN_BY_NAME: dict[str, Task] = {t.name: t for t in (*BUILTIN, *CONTINUOUS)}


class TaskMismatch(ValueError):
    """A :class:`Task` that does not fit its environment (or its own feature box)."""


def _check_box(task: Task) -> None:
    """The feature box: one finite interval ``low < high`` per named feature."""
    n = task.n_features
    if n == 0 or task.n_actions == 0:
        raise TaskMismatch(f"task {task.name} names {n} features and {task.n_actions} actions; "
                           "name at least one of each")
    if not len(task.low) == len(task.high) == n:
        raise TaskMismatch(f"task {task.name} names {n} features but gives {len(task.low)} low "
                           f"and {len(task.high)} high bounds; give one low and one high per "
                           "feature")
    with np.errstate(over="ignore", invalid="ignore"):
        low, high = np.asarray(task.low, dtype=float), np.asarray(task.high, dtype=float)
        span = high - low
    bad = ~(np.isfinite(low) & np.isfinite(high) & np.isfinite(span) & (low < high))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        if np.isfinite(low[i]) and np.isfinite(high[i]) and low[i] < high[i]:
            raise TaskMismatch(f"task {task.name}: feature {task.feature_names[i]!r} has the box "
                               f"[{low[i]}, {high[i]}], too wide to draw numbers from (its width "
                               "overflows); give the range of values the feature really takes")
        raise TaskMismatch(f"task {task.name}: feature {task.feature_names[i]!r} has the box "
                           f"[{low[i]}, {high[i]}]; low and high must be finite numbers with "
                           "low < high (the range of values random test states are drawn from)")


def _check_spaces(task: Task, obs_space: Any, act_space: Any) -> None:
    """The task's features and actions against the environment's spaces."""
    import gymnasium as gym

    env = f"the environment {task.gym_id}"
    if isinstance(obs_space, gym.spaces.Discrete):
        numbers = 1
    elif isinstance(obs_space, gym.spaces.Box):
        numbers = int(np.prod(obs_space.shape))
    else:
        raise TaskMismatch(f"{env} observes {obs_space}; Imitation-BT needs a Box or Discrete "
                           "observation space")
    if numbers != task.n_features:
        raise TaskMismatch(f"task {task.name} names {task.n_features} features "
                           f"({', '.join(task.feature_names)}) but {env} observes "
                           f"{numbers} number(s) (shape {obs_space.shape}); name one feature per "
                           "number of the observation")
    if task.continuous:
        if not (isinstance(act_space, gym.spaces.Box) and act_space.shape == (task.n_actions,)):
            raise TaskMismatch(f"task {task.name} names {task.n_actions} action dimension(s) but "
                               f"{env} acts in {act_space}; name one per dimension of its Box")
    elif not isinstance(act_space, gym.spaces.Discrete):
        raise TaskMismatch(f"{env} acts in {act_space}; Imitation-BT needs a Discrete action "
                           "space, or a Box with action_low and action_high given in the task")
    elif int(act_space.n) != task.n_actions:
        raise TaskMismatch(f"task {task.name} names {task.n_actions} actions "
                           f"({', '.join(task.action_names)}) but {env} has {int(act_space.n)}; "
                           "name one action per action of its Discrete space")


def check_task(task: Task) -> None:
    """``TaskMismatch`` (one line) unless ``task`` fits its environment: one feature per number
    of the observation, one action name per discrete action (or Box dimension), a finite box
    ``low < high`` per feature. The environment is made once to read its spaces; a failure to
    make it is a ``ValueError`` naming it."""
    _check_box(task)
    try:
        env = task.make_env()
    except Exception as err:
        raise ValueError(f"making the environment {task.gym_id} for task {task.name} failed "
                         f"({type(err).__name__}: {' '.join(str(err).split())}); fix its "
                         "constructor or its registration") from None
    try:
        _check_spaces(task, env.observation_space, env.action_space)
    finally:
        env.close()


_CHECKED: set[Task] = set()  # tasks found to fit their environment (made once, not each time)


def check_user_task(task: Task) -> None:
    """:func:`check_task` for a user's task (a built-in one is checked by the tests), once per
    task object and process."""
    builtin = BUILTIN_BY_NAME.get(task.name)
    if builtin is task:
        return
    try:
        if task in _CHECKED:
            return
    except TypeError:  # unhashable kwargs: check every time
        check_task(task)
        return
    check_task(task)
    _CHECKED.add(task)


def register_task(task: Task) -> Task:
    """Add (or replace) a task in the registry; returns it.

    The task is checked first (:func:`check_task`; ``TaskMismatch`` says what does not fit):
    against its environment where gymnasium already knows it, else when it is resolved."""
    import gymnasium as gym

    _check_box(task)
    if task.gym_id in gym.registry:
        check_task(task)
    TASKS[task.name] = task
    return task


for _task in (*BUILTIN, *CONTINUOUS):
    _check_box(_task)  # their environments are checked by the tests (making them all is slow)
    TASKS[_task.name] = _task


def get_task(name: str | Task) -> Task:
    """Look a task up by name; unknown names get the closest known ones in the message.

    A :class:`Task` is returned as it is (an unregistered or edited one too)."""
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


def task_from_env(gym_id: str, **kwargs: Any) -> Task:
    """A task for any gymnasium env with a flat Box (or Discrete) observation and discrete actions.

    Features are named ``x0, x1, ...`` and actions ``a0, a1, ...``; register a :class:`Task`
    yourself for readable names. Raises ``KeyError`` for an unknown env id and ``ValueError``
    for spaces Imitation-BT cannot handle.
    """
    import gymnasium as gym

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
    box: dict[str, Any] = {}
    if (isinstance(act_space, gym.spaces.Box) and len(act_space.shape) == 1
            and np.isfinite(act_space.low).all() and np.isfinite(act_space.high).all()):
        # continuous actions: each dimension a command, the tree merged into few
        n = act_space.shape[0]
        actions = tuple(f"u{i}" for i in range(n))
        box = {"action_low": tuple(map(float, act_space.low)),
               "action_high": tuple(map(float, act_space.high)),
               "budget": TaskBudget(max_leaf_nodes=BOX_MAX_LEAF_NODES)}
    elif not isinstance(act_space, gym.spaces.Discrete):
        raise ValueError(f"{gym_id} has actions {act_space}; Imitation-BT needs a Discrete "
                         "action space or a flat Box with finite bounds")
    else:
        actions = tuple(f"a{i}" for i in range(int(act_space.n)))
    if isinstance(obs_space, gym.spaces.Discrete):
        return Task(gym_id, gym_id, ("state",), actions, (0,), (int(obs_space.n) - 1,),
                    kwargs=kwargs, discrete_state=True, integer_features=True,
                    **{"budget": TaskBudget(max_leaf_nodes=DEFAULT_MAX_LEAF_NODES), **box})
    if not isinstance(obs_space, gym.spaces.Box):
        raise ValueError(f"{gym_id} observes {obs_space}; Imitation-BT needs a Box or Discrete "
                         "observation space")
    low = np.clip(obs_space.low.reshape(-1), -10, 10)
    high = np.clip(obs_space.high.reshape(-1), -10, 10)
    names = tuple(f"x{i}" for i in range(len(low)))
    return Task(gym_id, gym_id, names, actions, tuple(map(float, low)), tuple(map(float, high)),
                kwargs=kwargs, **box)


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
    except TaskMismatch as err:
        raise LookupError(f"the environment module {name!r} registers a task that does not fit: "
                          f"{err}") from None
    except Exception as err:  # the module's own code failed
        raise LookupError(f"the environment module {name!r} failed to import "
                          f"({type(err).__name__}: {err}); fix the module") from None


def resolve_task(name: str) -> Task:
    """A registered task, else one built from a gymnasium env id (:func:`task_from_env`).

    Gymnasium's ``module:EnvId`` form imports ``module`` first (it registers ``EnvId``); the
    task is then ``EnvId``, and its environments import ``module`` wherever they are made.
    """
    import gymnasium as gym

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


def _own_limit(task: Task) -> int | None:
    """The episode limit the task or its gymnasium registration sets (None: none)."""
    import gymnasium as gym

    if task.max_episode_steps is not None:
        return task.max_episode_steps
    if "max_episode_steps" in task.env_kwargs:
        return task.env_kwargs["max_episode_steps"]
    if task.setup_module:
        __import__(task.setup_module)
    try:
        return gym.spec(task.gym_id).max_episode_steps
    except gym.error.Error:
        return None


def with_episode_cap(task: Task, steps: int | None = None) -> tuple[Task, str | None]:
    """The task with its episodes cut at ``steps`` (the user's choice), else, where neither the
    task nor its environment sets a limit, at ``DEFAULT_MAX_EPISODE_STEPS`` with a one-line
    notice saying so (an episode that never ends would hang every rollout); the cap is part of
    the task's cache key (:attr:`Task.key`)."""
    if steps is not None:
        return replace(task, episode_cap=int(steps)), None
    if (task.episode_cap is not None or task.name in BUILTIN_BY_NAME
            or _own_limit(task) is not None):  # the catalogue's own episodes all end
        return task, None
    notice = (f"notice: {task.gym_id} sets no max_episode_steps, so its episodes are cut at "
              f"{DEFAULT_MAX_EPISODE_STEPS:,} steps; choose another cut with "
              "--max-episode-steps N, or set max_episode_steps in its gym.register")
    return replace(task, episode_cap=DEFAULT_MAX_EPISODE_STEPS), notice
