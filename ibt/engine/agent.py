"""The agent the pipeline distils: an SB3 checkpoint or a plain ``MODULE:FUNCTION`` callable.

One object carries what every stage needs of it: the task, the algorithm name that keys the
cache (``callable`` for a callable), the digest that identifies it (the checkpoint's bytes, or
the callable's module and name), the loaded expert (once per process: SB3's ``load`` re-applies
the checkpoint's saved seed) and the uniform random policy of its action space.

The agent is read once: the bytes digested travel with the object (:attr:`Agent.data`), and
every process loads the agent from those bytes (a private copy of the checkpoint, the
callable's source compiled from them), never from the user's path again, so a file replaced
while a run goes on (a training job saving to the same path) cannot have its results filed
under the digest of the one it replaced.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ibt.tasks.task import Task

CALLABLE = "callable"  #: the algorithm name of an agent given as ``MODULE:FUNCTION``
RANDOM_SEED = 0  #: the uniform random policy's generator


@dataclass(frozen=True)
class Agent:
    """An agent to distil: ``source`` is a checkpoint path or ``MODULE:FUNCTION``."""

    task: Task
    algo: str
    source: str
    digest: str
    #: the bytes ``digest`` was computed from (a checkpoint's, a callable's file); None for a
    #: callable given as an importable module name, checked against its digest when loaded
    data: bytes | None = field(default=None, repr=False, compare=False)

    @property
    def continuous(self) -> bool:
        return bool(self.task.continuous)

    @property
    def is_callable(self) -> bool:
        return self.algo == CALLABLE

    def load(self) -> Any:
        """The expert object (:class:`ibt.experts.expert.Expert` or a callable's twin)."""
        if self.data is not None:
            _DATA.setdefault(self.digest, self.data)
        return _load(self.task, self.algo, self.source, self.digest)

    def random_act(self, seed: int = RANDOM_SEED) -> Any:
        """``act`` of the uniform random policy over the task's actions (indices or Box
        vectors), from its own seeded generator."""
        if self.continuous:
            from ibt.experts.training import BoxRandomPolicy

            return BoxRandomPolicy(self.task, seed).act
        rng = np.random.default_rng(seed)
        n = self.task.n_actions
        return lambda obs: rng.integers(n, size=len(obs))


def sb3_agent(task: Task, algo: str, checkpoint: str | Path, *, check: bool = True) -> Agent:
    """An SB3 checkpoint; ``check``: loaded now, so its spaces are checked against the task
    before any work (else when a stage first needs it: a cached run never loads it)."""
    from ibt.files import file_digest

    path = Path(checkpoint)
    if path.is_file():
        from ibt.experts.checkpoint import MAX_CHECKPOINT_BYTES, check_regular_file

        check_regular_file(path, MAX_CHECKPOINT_BYTES, "SB3 checkpoint")
        data = path.read_bytes()
        agent = Agent(task, algo, str(checkpoint), hashlib.sha256(data).hexdigest()[:16], data)
    else:
        agent = Agent(task, algo, str(checkpoint), file_digest(path))
    if check:
        agent.load()
    return agent


def committed_agent(task: Task, algo: str, experts_dir: Path | None = None) -> Agent:
    """The committed expert of ``task`` and ``algo`` (``data/experts``, or ``experts_dir``),
    not loaded until a stage needs it."""
    from ibt.experts.expert import expert_path

    return sb3_agent(task, algo, expert_path(task, algo, experts_dir), check=False)


def callable_agent(task: Task, spec: str) -> Agent:
    """An agent given as ``MODULE:FUNCTION`` (observation -> action); see
    :mod:`ibt.experts.callable_agent` for the optional Q-values or action probabilities."""
    from ibt.experts.callable_agent import agent_source, source_digest

    data = agent_source(spec)
    agent = Agent(task, CALLABLE, spec, source_digest(spec, data), data)
    agent.load()
    return agent


_DATA: dict[str, bytes] = {}  # digest -> the agent's bytes, as they came with an Agent


@lru_cache(maxsize=8)
def _load(task: Task, algo: str, source: str, digest: str) -> Any:
    data = _DATA.get(digest)
    if algo == CALLABLE:
        from ibt.experts.callable_agent import load_callable_agent

        return load_callable_agent(task, source, data, digest)
    from ibt.experts.expert import load_expert

    if data is None:
        return load_expert(task, algo, source)
    private = _private_copy(digest, data, Path(source).suffix or ".zip")
    try:
        return load_expert(task, algo, private)
    except (ValueError, OSError) as err:  # name the user's file, not the private copy
        raise type(err)(str(err).replace(str(private.resolve()), source).replace(
            str(private), source)) from None


_PRIVATE: list[str] = []  # this process's folder of private copies (removed at exit)


def _private_copy(digest: str, data: bytes, suffix: str) -> Path:
    """The agent's bytes in a file of this process's own, named by their digest."""
    if not _PRIVATE:
        folder = tempfile.mkdtemp(prefix="ibt-agent-")
        _PRIVATE.append(folder)
        atexit.register(shutil.rmtree, folder, True)
    path = Path(_PRIVATE[0]) / f"{digest}{suffix}"
    if not path.exists():
        with open(path, "wb") as fh:
            fh.write(data)
        os.chmod(path, 0o400)
    return path
