"""An agent given as a plain Python callable, ``MODULE:FUNCTION``, used wherever an expert is.

``MODULE``: a ``.py`` file (loaded under a private name, its folder on ``sys.path`` while it
loads) or an importable module name; ``FUNCTION``: a callable in it, or a dotted path to one
(``pilot.act``). **The module is code**: loading it runs it; pass only agents you trust.
Conventions (attributes of the callable: ``act.batched = True``, or methods of an object):

- ``FUNCTION(obs)`` maps ONE raw observation (a copy) to an action: an ``int`` in ``0..n-1``
  (numpy integers count; floats, bools, one-hot vectors do not), or on a Box task a finite
  vector of the action shape (a number for one dimension), clipped to the Box.
- ``FUNCTION.batched = True``: it and its companion take the batch ``(n, ...)`` and answer one
  row per observation.
- Companion ``FUNCTION.q_values(obs)`` (per-action values; weight ``max Q - min Q``, as DQN) or
  ``FUNCTION.action_probabilities(obs)`` (>= 0, summing to 1; weight ``max log p - min log p``,
  as PPO; p floored at :data:`PROB_FLOOR`): what :meth:`CallableExpert.scores` returns. Neither:
  every weight is 1 (weighted methods resample uniformly, as DAgger) and ``scores`` raises
  ``TypeError``. Both, or either on a Box task (whose weights are 1): refused.

Actions are FUNCTION's own, never its companion's argmax. The agent sees observations only and
nothing here draws random numbers. :func:`agent_digest` identifies an agent in cache keys.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import operator
import sys
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ibt.experts.expert import Expert
from ibt.signals import check_time
from ibt.tasks.task import Task

#: bump when what an agent's answers become (actions, weights, scores) changes: cache keys move
VERSION = 1
ALGO = "callable"  #: the ``algo`` of every callable agent (records, cache keys)
PROB_FLOOR = 1e-12  #: probabilities below this count as it in log p (finite weights)


def parse_spec(spec: str) -> tuple[str, str, bool]:
    """``(module, function, is_file)`` of ``MODULE:FUNCTION``; ``ValueError`` when malformed."""
    module, sep, function = str(spec).rpartition(":")
    is_file = module.endswith(".py") or "/" in module or "\\" in module or Path(module).is_file()
    names = function.split(".") + ([] if is_file else module.split("."))
    if not sep or not module or not all(name.isidentifier() for name in names):
        raise ValueError(f"agent {spec!r} is not MODULE:FUNCTION (MODULE a .py file or module "
                         "name, FUNCTION a dotted Python name), e.g. agent.py:act or pkg.mod:act")
    return module, function, is_file


def _module_file(spec: str, module: str) -> Path:
    path = Path(module).expanduser()
    if not path.is_file():
        kind = ValueError if path.exists() else FileNotFoundError
        raise kind(f"agent {spec!r}: {path} is {'not a file' if path.exists() else 'missing'}; "
                   "pass the path of the agent's .py file")
    return path.resolve()


def _failed(spec: str, doing: str, err: BaseException, fix: str) -> ValueError:
    text = " ".join(f"{type(err).__name__}: {err}".split())
    return ValueError(f"agent {spec!r}: {doing} raised {text[:300]}; {fix}")


@functools.lru_cache(maxsize=32)  # each version of a file (its bytes' digest) runs once
def _load_file(path: str, digest: str, source: bytes) -> Any:
    """The module of ``source`` (the bytes of the file at ``path`` that were digested), run
    under a private name with ``path`` as its ``__file__``: never the file read again."""
    name = "_ibt_agent_" + hashlib.sha256(f"{path}\0{digest}".encode()).hexdigest()[:16]
    module = types.ModuleType(name)
    module.__file__ = path
    sys.modules[name] = module  # as an import does (dataclasses and the like look it up)
    sys.path.insert(0, folder := str(Path(path).parent))  # its neighbours import, as a script's
    try:
        exec(compile(source, path, "exec"), module.__dict__)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    finally:
        sys.path.remove(folder)
    return module


def _import(spec: str, module: str, is_file: bool, source: bytes | None = None) -> Any:
    if is_file:
        path = _module_file(spec, module)
        data = path.read_bytes() if source is None else source
        try:
            return _load_file(str(path), hashlib.sha256(data).hexdigest(), data)
        except (Exception, SystemExit) as err:
            raise _failed(spec, f"loading {path}", err, "fix the module (`python "
                          f"{path}` shows the traceback)") from err
    try:
        return importlib.import_module(module)
    except (Exception, SystemExit) as err:
        raise _failed(spec, f"importing {module}", err, "check the module name, or pass a .py "
                      f"file (`python -c 'import {module}'` shows the traceback)") from err


def load_callable_agent(task: Task, spec: str, source: bytes | None = None,
                        digest: str | None = None) -> CallableExpert:
    """The agent ``MODULE:FUNCTION`` as an expert of ``task``: ``FileNotFoundError`` for a
    missing file, else ``ValueError`` (one line naming ``spec`` and the fix) for a malformed
    spec, a module that fails to import, a missing or uncallable attribute.

    ``source``: the bytes of the ``.py`` file that were digested (:func:`agent_source`), run
    instead of the file read again; ``digest``: for a module given by name (imported, not run
    from bytes), :func:`agent_digest` it must still have (``ValueError`` if it changed)."""
    module_name, function, is_file = parse_spec(spec)
    target: Any = _import(spec, module_name, is_file, source)
    if digest is not None and not is_file and agent_digest(spec) != digest:
        raise ValueError(f"agent {spec!r}: its module changed while the run went on (its digest "
                         "is not the one the run's results are filed under); rerun once it is "
                         "no longer being written")
    for depth, part in enumerate(function.split(".")):
        try:
            target = getattr(target, part)
        except Exception as err:
            where = ".".join([module_name, *function.split(".")[:depth]])
            raise ValueError(f"agent {spec!r}: {where} has no attribute {part!r} ("
                             f"{type(err).__name__}); check the name after the colon") from err
    if not callable(target):
        raise ValueError(f"agent {spec!r}: {function} is a {type(target).__name__}, not a "
                         "callable; name a function mapping an observation to an action")
    return CallableExpert(task, spec, target)


def agent_digest(spec: str) -> str:
    """sha256 (hex) of an agent for cache keys: :data:`VERSION`, FUNCTION's name and the bytes
    of the module's file (a module without a source file: its name). Edits to other files it
    imports or data it reads are NOT seen: results from before such an edit stay cached."""
    return source_digest(spec, agent_source(spec))


def agent_source(spec: str) -> bytes | None:
    """The bytes of the agent's module file, read once (None: a module without a source
    file)."""
    module, _, is_file = parse_spec(spec)
    if is_file:
        source: Path | None = _module_file(spec, module)
    else:
        try:
            origin = importlib.util.find_spec(module).origin  # type: ignore[union-attr]
        except Exception:  # not found (None has no origin), or its package failed to import
            raise ValueError(f"agent {spec!r}: no module named {module!r} can be found; pass a "
                             ".py file, or add its package to PYTHONPATH") from None
        source = Path(origin) if origin and Path(origin).is_file() else None
    return source.read_bytes() if source is not None else None


def source_digest(spec: str, source: bytes | None) -> str:
    """:func:`agent_digest` of the agent whose module file holds ``source``."""
    module, function, _ = parse_spec(spec)
    digest = hashlib.sha256(f"ibt callable agent v{VERSION}\0{function}\0".encode())
    digest.update(source if source is not None else f"module {module}".encode())
    return digest.hexdigest()


def _bad(spec: str, what: str, where: int | str, value: Any, expected: str) -> ValueError:
    """A bad answer for observation ``where`` (an index) or for the whole batch."""
    place = f"observation {where} of the batch" if isinstance(where, int) else where
    answer = " ".join(repr(value).split())[:80]
    return ValueError(f"agent {spec!r}: {what} answered {answer} for {place}; expected {expected}")


class CallableExpert(Expert):
    """A Python callable as an :class:`Expert` (``algo`` ``"callable"``): it overrides every
    public method, and has no SB3 ``model`` (None), so it goes wherever an Expert does."""

    def __init__(self, task: Task, spec: str, function: Callable[..., Any]) -> None:
        self.task, self.spec, self.function = task, spec, function
        self.algo, self.model, self.obs_norm = ALGO, None, None
        self.continuous, self.n_actions = task.continuous, task.n_actions
        self.batched = getattr(function, "batched", False) is True
        given = {name: getattr(function, name) for name in ("q_values", "action_probabilities")
                 if getattr(function, name, None) is not None}
        if len(given) > 1 or (given and self.continuous) or not all(map(callable, given.values())):
            raise ValueError(f"agent {spec!r} defines {' and '.join(given)}: give at most one, "
                             "a callable of the observation, and none on a Box task "
                             f"({task.name} is {'a Box' if self.continuous else 'discrete'})")
        self.companion = next(iter(given.items()), None)

    def _call(self, function: Callable[..., Any], what: str, obs: np.ndarray) -> list[Any]:
        """``function``'s answers, one per observation (one call on the batch if batched)."""
        check_time()  # between the environment's steps: the run's time cap holds here
        answers = []
        for i, x in enumerate([obs] if self.batched else obs):
            where = f"a batch of {len(obs)}" if self.batched else f"observation {i}"
            try:
                answers.append(function(x.copy() if isinstance(x, np.ndarray) else x))
            except (Exception, SystemExit) as err:  # sys.exit in an agent is its failure
                raise _failed(self.spec, f"{what} on {where}", err, "an agent answers, it "
                              "does not exit; fix the agent" if isinstance(err, SystemExit)
                              else "fix the agent") from err
        if not self.batched:
            return answers
        try:  # a number or a ragged answer is no batch either
            rows = list(answers[0]) if np.ndim(answers[0]) else []
        except (TypeError, ValueError):
            rows = []
        if len(rows) != len(obs):
            raise _bad(self.spec, what, f"a batch of {len(obs)}", answers[0],
                       "one row per observation (the agent is batched)")
        return rows

    def _floats(self, answers: list[Any], what: str, width: int, expected: str,
                scalar_ok: bool = False, probabilities: bool = False) -> np.ndarray:
        """``(n, width)`` float64 of finite answers (probabilities: >= 0, summing to 1)."""
        out = np.zeros((len(answers), width))
        for i, value in enumerate(answers):
            try:
                row = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                row = np.full(0, np.nan)
            ok = row.shape in ((width,), () if scalar_ok else (width,)) and np.isfinite(row).all()
            if ok and probabilities:
                ok = bool((row >= 0).all()) and abs(row.sum() - 1.0) <= 1e-3
            if not ok:
                raise _bad(self.spec, what, i, value, expected)
            out[i] = row
        return out

    def act(self, obs: np.ndarray) -> np.ndarray:
        """FUNCTION's actions for a batch: ``(n,)`` int64 (discrete), or ``(n, dims)`` float32
        clipped to the Box; ``ValueError`` names the first bad answer."""
        answers = self._call(self.function, "the agent", np.asarray(obs))
        n = self.n_actions
        if self.continuous:
            vectors = self._floats(answers, "the agent", n, f"a finite action vector of {n} "
                                   "number(s)", scalar_ok=n == 1)
            low, high = np.asarray(self.task.action_low), np.asarray(self.task.action_high)
            return np.clip(vectors, low, high).astype(np.float32)
        actions = np.zeros(len(answers), dtype=np.int64)
        for i, value in enumerate(answers):
            try:
                action = -1 if isinstance(value, bool | np.bool_) else operator.index(value)
            except TypeError:
                action = -1
            if not 0 <= action < n:
                raise _bad(self.spec, "the agent", i, value, f"an integer action in 0..{n - 1}")
            actions[i] = action
        return actions

    def scores(self, obs: np.ndarray) -> np.ndarray:
        """``(n, n_actions)``: the companion's Q-values, or log-probabilities (floored at
        :data:`PROB_FLOOR`); ``TypeError`` without a companion (always so on a Box task)."""
        if self.companion is None:
            raise TypeError(f"agent {self.spec!r} has no per-action scores (Box task, or "
                            "neither q_values nor action_probabilities given); use act or label")
        name, function = self.companion
        answers = self._call(function, name, np.asarray(obs))
        if name == "q_values":
            return self._floats(answers, name, self.n_actions, f"{self.n_actions} finite values")
        rows = self._floats(answers, name, self.n_actions, f"{self.n_actions} finite "
                            "probabilities summing to 1", probabilities=True)
        return np.log(np.maximum(rows / rows.sum(axis=1, keepdims=True), PROB_FLOOR))

    def label(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """FUNCTION's actions, weighted by ``max - min`` of :meth:`scores` (else ones)."""
        actions = self.act(obs)
        if self.companion is None:
            return actions, np.ones(len(actions))
        scores = self.scores(obs)
        return actions, scores.max(axis=1) - scores.min(axis=1)

    def action_loss(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Not available: a callable agent has no critic to price another action."""
        raise TypeError(f"agent {self.spec!r} has no critic; action_loss needs an SB3 expert")
