"""Mixing schedules beta_i: the probability that the expert acts at iteration i.

Iterations are numbered from 0 here. With the paper's 1-based index j = i + 1:
``linear`` is beta = 1 - i/N (1 at the first iteration, 1/N at the last), ``exponential(p)`` is
beta = p**(j-1) = p**i (DAgger), ``constant(c)`` is c every iteration (c = 1: Behavior Cloning),
and ``first_only`` is 1 then 0 (VIPER: expert rollouts first, the learner's after).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Schedule:
    """A named, parameterised beta schedule; call it with (iteration, n_iterations)."""

    kind: str
    p: float = 0.5

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown schedule {self.kind!r}; expected one of {', '.join(KINDS)}")
        if not 0.0 <= self.p <= 1.0:
            raise ValueError(f"schedule parameter p must lie in [0, 1], got {self.p}")

    def __call__(self, i: int, n: int) -> float:
        if not 0 <= i < n:
            raise ValueError(f"iteration {i} outside 0..{n - 1}")
        if self.kind == "linear":
            return 1.0 - i / n
        if self.kind == "exponential":
            return self.p ** i
        if self.kind == "constant":
            return self.p
        return 1.0 if i == 0 else 0.0  # first_only

    def values(self, n: int) -> list[float]:
        return [self(i, n) for i in range(n)]

    @property
    def label(self) -> str:
        if self.kind == "exponential":
            return f"exponential p={self.p:g}"
        if self.kind == "constant":
            return f"constant {self.p:g}"
        return self.kind


KINDS = ("linear", "exponential", "constant", "first_only")


def linear() -> Schedule:
    return Schedule("linear")


def exponential(p: float) -> Schedule:
    return Schedule("exponential", p)


def constant(c: float) -> Schedule:
    return Schedule("constant", c)


def first_only() -> Schedule:
    return Schedule("first_only")
