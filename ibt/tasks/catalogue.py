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
from ibt.tasks.settings import BOX_MAX_LEAF_NODES, DEFAULT_MAX_LEAF_NODES, TaskBudget
from ibt.tasks.task import Task, sdl_video_driver

__all__ = ["TASKS", "Task", "get_task", "import_env_module", "register_task", "resolve_task",
           "sdl_video_driver", "task_from_env"]

TASKS: dict[str, Task] = {}


def register_task(task: Task) -> Task:
    """Add (or replace) a task in the registry; returns it."""
    TASKS[task.name] = task
    return task


for _task in (*BUILTIN, *CONTINUOUS):
    register_task(_task)


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
        # continuous actions (issue 25): each dimension a command, the tree merged into few
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
