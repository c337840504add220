"""Hand-written and symbolic controllers our BTs are measured beside, run by the project.

* **Gymnasium's LunarLander heuristic** (``gymnasium.envs.box2d.lunar_lander.heuristic``), the
  controller that ships with the environment: two linear targets over three or four features,
  a legs-contact override, then four if/elif rules (discrete actions) or two proportional
  commands (continuous), 12 constants.
* **DSP's symbolic policies** (Landajuela et al., "Discovering symbolic policies with deep
  reinforcement learning", ICML 2021): the final formulas published in their repository
  (``dso-org/deep-symbolic-optimization``, ``dso/dso/task/control/scripts/policy_eval.py``),
  kept here as the prefix token strings they are published as and evaluated by a small
  interpreter of their operators (no code is read from data). Their MountainCarContinuous
  formula (``log(cos 1) / log(velocity)``) is left out: it is undefined (the logarithm of a
  negative number) whenever the car moves left, so it cannot be run as published.

Each is a policy on raw observation batches (the callable-agent shape), measured on the same
episodes as our BTs, with its size in comparable units: rules (if/elif branches or formulas),
terms (feature reads) and constants.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: DSP's operators: name -> (arity, function on float arrays); unprotected, as published
_OPERATORS: dict[str, tuple[int, Callable[..., np.ndarray]]] = {
    "add": (2, np.add), "sub": (2, np.subtract), "mul": (2, np.multiply),
    "div": (2, np.divide), "sin": (1, np.sin), "cos": (1, np.cos), "exp": (1, np.exp),
    "log": (1, np.log),
}


@dataclass(frozen=True)
class Reference:
    """A controller run beside our BTs: its source, task, size and policy."""

    name: str
    source: str
    task: str
    rules: int  # branches of an if/elif chain, or formulas (one per action dimension)
    terms: int  # reads of an observed feature
    constants: int
    act: Callable[[np.ndarray], np.ndarray]


def prefix_formula(tokens: str) -> tuple[Callable[[np.ndarray], np.ndarray], int, int]:
    """A DSP prefix token string (``add,mul,-2.0,x2,x1``; ``x1`` is observation 0) as a
    function of observation batches, with its counts of feature reads and constants."""
    items = tokens.split(",")
    position = 0
    reads = constants = 0

    def parse() -> Callable[[np.ndarray], np.ndarray]:
        nonlocal position, reads, constants
        if position >= len(items):
            raise ValueError(f"formula {tokens!r:.80} ends early")
        token = items[position].strip()
        position += 1
        if token in _OPERATORS:
            arity, fn = _OPERATORS[token]
            args = [parse() for _ in range(arity)]
            return lambda x: fn(*(a(x) for a in args))
        if token.startswith("x") and token[1:].isdigit():
            column = int(token[1:]) - 1
            reads += 1
            return lambda x: x[:, column]
        value = float(token)
        if not math.isfinite(value):
            raise ValueError(f"formula {tokens!r:.80} holds the constant {token!r}")
        constants += 1
        return lambda x: np.full(len(x), value)

    fn = parse()
    if position != len(items):
        raise ValueError(f"formula {tokens!r:.80} has tokens after its end")
    return fn, reads, constants


def _dsp(name: str, task: str, formulas: tuple[str, ...]) -> Reference:
    parsed = [prefix_formula(f) for f in formulas]

    def act(obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float64)
        with np.errstate(all="ignore"):
            return np.column_stack([fn(x) for fn, _, _ in parsed]).astype(np.float32)

    return Reference(name, "DSP (Landajuela et al., ICML 2021), published formulas", task,
                     rules=len(parsed), terms=sum(r for _, r, _ in parsed),
                     constants=sum(c for _, _, c in parsed), act=act)


def _heuristic(task: str, continuous: bool) -> Reference:
    from types import SimpleNamespace

    from gymnasium.envs.box2d.lunar_lander import heuristic

    env = SimpleNamespace(unwrapped=SimpleNamespace(continuous=continuous))

    def act(obs: np.ndarray) -> np.ndarray:
        actions = [heuristic(env, row) for row in np.asarray(obs)]
        return (np.asarray(actions, dtype=np.float32) if continuous
                else np.asarray(actions, dtype=np.int64))

    # angle_targ = 0.5 x + vx (clipped), hover_targ = 0.55 |x|, angle_todo = (targ - angle)
    # * 0.5 - vangle, hover_todo = (targ - y) * 0.5 - vy * 0.5, the legs override (vy * 0.5),
    # then 4 if/elif rules (discrete: 0.05 thresholds) or 2 commands (continuous)
    return Reference("Gymnasium heuristic", "gymnasium.envs.box2d.lunar_lander.heuristic",
                     task, rules=2 if continuous else 4, terms=10, constants=12, act=act)


#: DSP's LunarLanderContinuous formulas (main engine, side engine), as published
DSP_LUNAR_LANDER = (
    "add,add,mul,0.7624715039886016,sub,sin,x3,add,add,add,add,div,add,sin,add,"
    "0.09101695879983959,0.0922444066126055,add,x2,x4,0.11289444161591844,x4,x4,x4,x4,"
    "-0.0008359813574848967,-0.12271695008045375",
    "add,add,mul,0.24326721693967257,div,div,x4,log,sin,1.019536868443063,sub,x6,x3,"
    "-0.07620830192712105,0.07787010100098943",
)
#: DSP's Pendulum formula, ``-2 sin + (-8 sin - 2 thdot) / cos`` (x1 cos, x2 sin, x3 thdot)
DSP_PENDULUM = ("add,mul,-2.0,x2,div,add,mul,-8.0,x2,mul,-2.0,x3,x1",)


def references(task: str | None = None) -> list[Reference]:
    """The reference controllers (of ``task`` only, when given)."""
    every = [
        _heuristic("LunarLander-v3", continuous=False),
        _heuristic("LunarLanderContinuous-v3", continuous=True),
        _dsp("DSP formulas", "LunarLanderContinuous-v3", DSP_LUNAR_LANDER),
        _dsp("DSP formula", "Pendulum-v1", DSP_PENDULUM),
    ]
    return [r for r in every if task is None or r.task == task]
