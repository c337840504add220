"""The pipeline's wall-clock budget: the deadline, the grace a step under way gets past it, and
the pace (seconds a step, steps an episode) that foretells the least a step can take."""

from __future__ import annotations

import time
from collections.abc import Callable

from ibt.engine import measure

#: a step under way when the budget runs out may finish within this share of the budget past
#: it (at least ``GRACE_MIN`` seconds), else it is cut: LunarLander's 30-minute runs ended
#: 0-40 s past their budget with a search that began late and gave the run's best BT, while a
#: 15-minute one was still in its first search at 16 minutes (a search there takes about 20
#: minutes on two cores); a grace chosen after seeing those runs, to keep the former's search
#: and cut the latter's
GRACE_SHARE = 0.1
GRACE_MIN = 60.0
#: the pace of a rerun that read every measurement from the cache: its last tree timed anew
PACE_EPISODES = 2


class Deadline:
    """A wall-clock budget from now (``None``: no limit)."""

    def __init__(self, seconds: float | None, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.seconds, self.clock = seconds, clock
        self.start = clock()
        self._grace: float | None = None

    def passed(self) -> bool:
        return self.seconds is not None and self.clock() - self.start >= self.seconds

    def elapsed(self) -> float:
        return self.clock() - self.start

    def left(self) -> float:
        """Seconds left (infinite without a limit)."""
        return float("inf") if self.seconds is None else self.seconds - self.elapsed()

    def grace(self) -> float:
        """Seconds past the budget a step under way may take before it is cut."""
        if self._grace is not None:
            return self._grace
        return 0.0 if self.seconds is None else max(GRACE_MIN, GRACE_SHARE * self.seconds)

    def reserving(self, seconds: float) -> Deadline:
        """The same budget from the same start, less ``seconds`` kept for work after it (the
        pipeline's confirmation), and its grace the same as this one's."""
        inner = Deadline(None if self.seconds is None else max(self.seconds - seconds, 0.0),
                         self.clock)
        inner.start = self.start
        inner._grace = self.grace()
        return inner


class Pace:
    """How fast the run's tree measurements stepped, and how long their episodes were: the
    least a step of ``episodes`` can take (each episode as long as the shorter of the agent's
    and the measured trees' mean episode)."""

    def __init__(self, agent_length: float | None = None) -> None:
        self.agent_length = agent_length
        self.seconds, self.steps, self.episodes = 0.0, 0, 0

    def add(self, measured: measure.Returns) -> None:
        """Count a measurement rolled out now (one read from the cache has no wall time)."""
        if measured.seconds is not None and measured.lengths:
            self.seconds += measured.seconds
            self.steps += sum(measured.lengths)
            self.episodes += len(measured.lengths)

    def length(self) -> float:
        """Steps an episode: the shorter of the agent's and the measured trees' mean."""
        mean = self.steps / self.episodes if self.episodes else float("inf")
        return min(mean, self.agent_length or float("inf"))

    def least(self, episodes: float) -> float:
        """Seconds ``episodes`` take at least (0 before any measurement was timed)."""
        return episodes * self.length() * self.seconds / self.steps if self.steps else 0.0

    def said(self, episodes: float) -> str:
        return (f"{episodes:,.0f} episodes of {self.length():.0f} steps at the "
                f"{1e6 * self.seconds / self.steps:.0f} us a step this run's tree measurements "
                "took")
