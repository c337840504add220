"""The agent the pipeline distils: an SB3 checkpoint or a plain ``MODULE:FUNCTION`` callable.

One object carries what every stage needs of it: the task, the algorithm name that keys the
cache (``callable`` for a callable), the digest that identifies it (the checkpoint's bytes, or
the callable's module and name), the loaded expert (once per process: SB3's ``load`` re-applies
the checkpoint's saved seed) and the uniform random policy of its action space.
"""

from __future__ import annotations

from dataclasses import dataclass
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

    @property
    def continuous(self) -> bool:
        return bool(self.task.continuous)

    @property
    def is_callable(self) -> bool:
        return self.algo == CALLABLE

    def load(self) -> Any:
        """The expert object (:class:`ibt.experts.expert.Expert` or a callable's twin)."""
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

    agent = Agent(task, algo, str(checkpoint), file_digest(Path(checkpoint)))
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
    from ibt.experts.callable_agent import agent_digest

    agent = Agent(task, CALLABLE, spec, agent_digest(spec))
    agent.load()
    return agent


@lru_cache(maxsize=8)
def _load(task: Task, algo: str, source: str, _digest: str) -> Any:
    if algo == CALLABLE:
        from ibt.experts.callable_agent import load_callable_agent

        return load_callable_agent(task, source)
    from ibt.experts.expert import load_expert

    return load_expert(task, algo, source)
