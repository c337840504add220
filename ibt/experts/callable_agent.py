"""An agent given as a plain Python callable, ``MODULE:FUNCTION``, used wherever an expert is.

``MODULE`` is a path to a ``.py`` file (loaded under a private module name, its folder on
``sys.path`` while it loads, so it may import its neighbours at the top) or an importable
dotted module name; ``FUNCTION`` a callable in it, or a dotted attribute path to one
(``policy.act`` for a method of a module-level object). **The module is code**: loading it runs
it, so pass only agents you trust, as with a checkpoint.

Conventions, all attributes of the callable itself (on a function: ``act.batched = True``;
on an object with ``__call__``: its methods; on a bound method: its function's attributes):

- ``FUNCTION(obs)`` maps ONE raw observation (a copy, so edits do not reach us) to an action:
  an ``int`` in ``0..n-1`` on a discrete task (a numpy integer or 0-d integer array counts;
  floats, bools and one-hot vectors do not), a finite vector of the action shape on a Box task
  (a plain number where the Box has one dimension), clipped to the Box.
- ``FUNCTION.batched = True``: FUNCTION (and the companions below) take the whole batch
  ``(n, ...)`` and return ``(n,)`` integers, ``(n, dims)`` vectors or ``(n, n_actions)`` values.
- ``FUNCTION.q_values(obs)``: per-action values; the weight of a state is ``max Q - min Q`` (as
  for a DQN expert), and :meth:`CallableExpert.scores` returns them.
- ``FUNCTION.action_probabilities(obs)``: per-action probabilities (>= 0, summing to 1); the
  weight is ``max log p - min log p`` (as for a PPO expert; p floored at :data:`PROB_FLOOR`).
- Neither: every weight is 1 (the weighted methods then resample uniformly, as plain DAgger),
  and ``scores`` raises ``TypeError``. Both: refused. On a Box task neither is allowed, and the
  weights are 1.

The actions are FUNCTION's own, never the argmax of its companion. The agent sees observations
only; nothing here draws random numbers. :func:`agent_digest` identifies an agent in cache keys.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import operator
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ibt.experts.expert import Expert
from ibt.tasks.task import Task

#: bump when what an agent's answers become (actions, weights, scores) changes: cache keys move
VERSION = 1
ALGO = "callable"  #: the ``algo`` of every callable agent (records, cache keys)
PROB_FLOOR = 1e-12  #: probabilities below this count as it in log p (finite weights)
MAX_MODULE_BYTES = 16 << 20
COMPANIONS = ("q_values", "action_probabilities")
_EXAMPLE = "e.g. my_agent.py:act or my_package.agents:act"


def parse_spec(spec: str) -> tuple[str, str, bool]:
    """``(module, function, is_file)`` of ``MODULE:FUNCTION``; ``ValueError`` when malformed."""
    module, sep, function = str(spec).rpartition(":")
    if not sep or not module or not function:
        raise ValueError(f"agent {spec!r} is not MODULE:FUNCTION; name a .py file or module and "
                         f"the callable in it, {_EXAMPLE}")
    if not all(part.isidentifier() for part in function.split(".")):
        raise ValueError(f"agent {spec!r}: {function!r} is not a (dotted) Python name; name the "
                         f"callable after the colon, {_EXAMPLE}")
    is_file = module.endswith(".py") or "/" in module or "\\" in module or Path(module).is_file()
    if not is_file and not all(part.isidentifier() for part in module.split(".")):
        raise ValueError(f"agent {spec!r}: {module!r} is neither a .py file nor a module name; "
                         f"{_EXAMPLE}")
    return module, function, is_file


def _module_file(spec: str, module: str) -> Path:
    path = Path(module).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"agent {spec!r}: no file {path}; pass the path of the .py file "
                                "that defines the agent")
    if not path.is_file() or path.stat().st_size > MAX_MODULE_BYTES:
        raise ValueError(f"agent {spec!r}: {path} is not a Python source file (a folder, a "
                         f"device or over {MAX_MODULE_BYTES:,} bytes); pass the agent's .py file")
    return path.resolve()


def _failed(spec: str, doing: str, err: BaseException, fix: str) -> ValueError:
    text = " ".join(f"{type(err).__name__}: {err}".split())
    return ValueError(f"agent {spec!r}: {doing} raised {text[:300]}; {fix}")


@functools.lru_cache(maxsize=32)
def _load_file(path: str, _mtime: int, _size: int) -> Any:
    """The module of ``path``, executed once per version of the file (mtime and size)."""
    name = "_ibt_agent_" + hashlib.sha256(path.encode()).hexdigest()[:16]
    loader_spec = importlib.util.spec_from_file_location(name, path)
    if loader_spec is None or loader_spec.loader is None:
        raise ImportError(f"{path} is not loadable as Python source")
    module = importlib.util.module_from_spec(loader_spec)
    sys.modules[name] = module  # as an import does (dataclasses and the like look it up)
    folder = str(Path(path).parent)
    sys.path.insert(0, folder)
    try:
        loader_spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    finally:
        sys.path.remove(folder)
    return module


def _import(spec: str, module: str, is_file: bool) -> Any:
    if is_file:
        path = _module_file(spec, module)
        stat = path.stat()
        try:
            return _load_file(str(path), stat.st_mtime_ns, stat.st_size)
        except (Exception, SystemExit) as err:
            raise _failed(spec, f"loading {path}", err, "fix the module (`python "
                          f"{path}` shows the traceback)") from err
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name is not None and (module == err.name or module.startswith(err.name + ".")):
            raise ValueError(f"agent {spec!r}: no module named {module!r} on the Python path; "
                             "pass a .py file path instead, or install or add its package to "
                             "PYTHONPATH") from None
        raise _failed(spec, f"importing {module}", err, "install what the module imports") from err
    except (Exception, SystemExit) as err:
        raise _failed(spec, f"importing {module}", err, f"fix the module (`python -c 'import "
                      f"{module}'` shows the traceback)") from err


def load_callable_agent(task: Task, spec: str) -> CallableExpert:
    """The agent ``MODULE:FUNCTION`` as an expert of ``task`` (see the module docstring).

    ``FileNotFoundError`` for a missing file; ``ValueError`` (one line naming ``spec`` and the
    fix) for a malformed spec, a module that fails to import, a missing or uncallable attribute.
    """
    module_name, function, is_file = parse_spec(spec)
    target: Any = _import(spec, module_name, is_file)
    for depth, part in enumerate(function.split(".")):
        try:
            target = getattr(target, part)
        except AttributeError:
            where = ".".join([module_name, *function.split(".")[:depth]]) if depth else module_name
            raise ValueError(f"agent {spec!r}: {where} has no attribute {part!r}; check the name "
                             "after the colon") from None
        except Exception as err:
            raise _failed(spec, f"looking up {part}", err, "check the name after the colon"
                          ) from err
    if not callable(target):
        raise ValueError(f"agent {spec!r}: {function} is a {type(target).__name__}, not a "
                         "callable; name a function mapping an observation to an action")
    return CallableExpert(task, spec, target)


def agent_digest(spec: str) -> str:
    """sha256 (hex) of an agent for cache keys: :data:`VERSION`, FUNCTION's name and the module
    file's bytes (a module name: the file it resolves to; a module without a source file: its
    name only). Edits to other files the module imports, or to data it reads, are NOT seen:
    a result computed before such an edit is served from the cache."""
    module, function, is_file = parse_spec(spec)
    source: Path | None = _module_file(spec, module) if is_file else None
    if not is_file:
        try:
            found = importlib.util.find_spec(module)
        except (ImportError, ValueError):
            found = None
        if found is None:
            raise ValueError(f"agent {spec!r}: no module named {module!r} on the Python path; "
                             "pass a .py file path instead, or add its package to PYTHONPATH")
        origin = found.origin
        source = Path(origin) if origin and Path(origin).is_file() else None
    digest = hashlib.sha256(f"ibt callable agent v{VERSION}\0{function}\0".encode())
    digest.update(source.read_bytes() if source is not None else f"module {module}".encode())
    return digest.hexdigest()


def _short(value: Any) -> str:
    return " ".join(repr(value).split())[:80]


class CallableExpert(Expert):
    """A Python callable as an :class:`Expert` (``algo`` ``"callable"``): it overrides every
    public method, and has no SB3 ``model`` (None), so it goes wherever an Expert does."""

    def __init__(self, task: Task, spec: str, function: Callable[..., Any]) -> None:
        self.task, self.spec, self.function = task, spec, function
        self.algo, self.model, self.obs_norm = ALGO, None, None
        self.continuous = task.continuous
        self.n_actions = task.n_actions
        self.batched = getattr(function, "batched", False) is True
        found = {name: getattr(function, name, None) for name in COMPANIONS}
        given = {name: f for name, f in found.items() if f is not None}
        if len(given) > 1 or (given and self.continuous):
            raise ValueError(f"agent {spec!r} defines {' and '.join(given)}: give at most one of "
                             f"q_values and action_probabilities, and none on a Box task ("
                             f"{task.name} is {'a Box' if self.continuous else 'discrete'})")
        for name, companion in given.items():
            if not callable(companion):
                raise ValueError(f"agent {spec!r}: its {name} is a {type(companion).__name__}, "
                                 "not a callable; make it a function of the observation")
        self.companion = next(iter(given.items()), None)

    def _call(self, function: Callable[..., Any], what: str, obs: np.ndarray) -> list[Any]:
        """``function``'s answers, one per observation (one call on the batch if batched)."""
        if self.batched:
            try:
                out = function(np.array(obs))
            except Exception as err:
                raise _failed(self.spec, f"{what} on a batch of {len(obs)}", err,
                              "fix the agent") from err
            arr = np.asarray(out) if not isinstance(out, np.ndarray) else out
            if arr.ndim == 0 or len(arr) != len(obs):
                raise ValueError(f"agent {self.spec!r}: {what} (batched) answered "
                                 f"{_short(out)} for {len(obs)} observations; return one row "
                                 "per observation")
            return list(arr)
        answers = []
        for i, row in enumerate(obs):
            try:
                answers.append(function(row.copy() if isinstance(row, np.ndarray) else row))
            except Exception as err:
                raise _failed(self.spec, f"{what} on observation {i}", err,
                              "fix the agent") from err
        return answers

    def _bad(self, what: str, index: int, value: Any, expected: str) -> ValueError:
        return ValueError(f"agent {self.spec!r}: {what} answered {_short(value)} for observation "
                          f"{index} of the batch; expected {expected}")

    def act(self, obs: np.ndarray) -> np.ndarray:
        """FUNCTION's actions for a batch: ``(n,)`` int64 (discrete), or ``(n, dims)`` float32
        clipped to the Box; ``ValueError`` names the first bad answer."""
        obs = np.asarray(obs)
        answers = self._call(self.function, "the agent", obs)
        if self.continuous:
            return self._vectors(answers)
        actions = np.zeros(len(answers), dtype=np.int64)
        for i, value in enumerate(answers):
            try:
                action = -1 if isinstance(value, bool | np.bool_) else operator.index(value)
            except TypeError:
                action = -1
            if not 0 <= action < self.n_actions:
                raise self._bad("the agent", i, value,
                                f"an integer action in 0..{self.n_actions - 1}")
            actions[i] = action
        return actions

    def _vectors(self, answers: list[Any]) -> np.ndarray:
        dims = self.n_actions
        out = np.zeros((len(answers), dims), dtype=np.float64)
        for i, value in enumerate(answers):
            try:
                vector = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                vector = np.full(0, np.nan)
            shape_ok = vector.shape == (dims,) or (dims == 1 and vector.shape == ())
            if not shape_ok or not np.isfinite(vector).all():
                raise self._bad("the agent", i, value,
                                f"a finite action vector of {dims} number(s)")
            out[i] = vector
        low, high = np.asarray(self.task.action_low), np.asarray(self.task.action_high)
        return np.clip(out, low, high).astype(np.float32)

    def scores(self, obs: np.ndarray) -> np.ndarray:
        """``(n, n_actions)``: the companion's Q-values, or log-probabilities (floored at
        :data:`PROB_FLOOR`); ``TypeError`` without a companion or on a Box task."""
        if self.companion is None:
            raise TypeError(f"agent {self.spec!r} has no per-action scores (Box task, or "
                            "neither q_values nor action_probabilities given); use act or label")
        name, function = self.companion
        obs = np.asarray(obs)
        answers = self._call(function, name, obs)
        rows = np.zeros((len(answers), self.n_actions))
        probabilities = name == "action_probabilities"
        for i, value in enumerate(answers):
            try:
                row = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                row = np.full(0, np.nan)
            ok = row.shape == (self.n_actions,) and bool(np.isfinite(row).all())
            if ok and probabilities:
                ok = bool((row >= 0).all()) and abs(row.sum() - 1.0) <= 1e-3
            if not ok:
                raise self._bad(name, i, value, f"{self.n_actions} finite "
                                + ("probabilities summing to 1" if probabilities else "values"))
            rows[i] = row
        if probabilities:
            return np.log(np.maximum(rows / rows.sum(axis=1, keepdims=True), PROB_FLOOR))
        return rows

    def label(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """FUNCTION's actions and the weights: ``max - min`` of :meth:`scores` where a companion
        is given, else ones."""
        actions = self.act(obs)
        if self.companion is None:
            return actions, np.ones(len(actions))
        scores = self.scores(obs)
        return actions, scores.max(axis=1) - scores.min(axis=1)

    def action_loss(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Not available: a callable agent has no critic to price another action."""
        raise TypeError(f"agent {self.spec!r} has no critic: action_loss needs an SB3 SAC, TD3 "
                        "or PPO expert")
