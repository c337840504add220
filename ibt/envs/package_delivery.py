"""Package delivery: a small, fully observable robot domain for distilling RL agents into BTs.

A robot serves two loading zones (``zone_a``, ``zone_b``) that produce materials which are
*light* or *heavy* at random, a ``depot`` where materials are delivered, and a ``charger``.
Every place is one step away from every other place.

Observation (``spaces.MultiDiscrete([4, 11, 3, 3, 3])``, dtype ``int64``), see ``FEATURE_NAMES``
and ``FEATURE_VALUES``:

=========  ======  ==========================================================
feature    values  meaning
=========  ======  ==========================================================
location   0..3    0 depot, 1 zone_a, 2 zone_b, 3 charger
battery    0..10   integer charge level (10 = full)
carrying   0..2    0 none, 1 light, 2 heavy
zone_a     0..2    material waiting at zone A: 0 none, 1 light, 2 heavy
zone_b     0..2    material waiting at zone B: 0 none, 1 light, 2 heavy
=========  ======  ==========================================================

The categorical codes are ordinal (none < light < heavy) so threshold tests ``obs[f] <= t`` read
naturally. The observation is the whole state: the dynamics below depend on nothing else
(besides the constructor parameters), so the domain is Markov.

Actions (``spaces.Discrete(8)``, see ``ACTION_NAMES``): ``go_depot``, ``go_zone_a``,
``go_zone_b``, ``go_charger``, ``load``, ``unload``, ``charge``, ``wait``.

Dynamics of one step, in order (``s = drain_scale``, default 1; ``w = 1`` when the material
being moved or handled is heavy, else ``0``):

1. The action is applied and costs battery:

   ==============================  =========================================  ============
   action                          effect                                     battery cost
   ==============================  =========================================  ============
   ``go_<place>`` (other place)    robot moves there (carried material too)   ``s + w``
   ``load`` at a zone with         material goes from the zone to the robot   ``s + w``
   material and empty hands
   ``unload`` at the depot while   material delivered, hands empty            ``s + w``
   carrying
   ``charge`` at the charger       battery ``+= 4`` capped at 10              ``0``
   ``wait``                        nothing                                    ``s``
   invalid action                  nothing, penalty ``-1``                    ``s``
   ==============================  =========================================  ============

   Invalid actions are: ``go_<place>`` to the current place, ``load`` away from a zone, with
   nothing waiting or with full hands, ``unload`` away from the depot or with empty hands, and
   ``charge`` away from the charger. ``charge`` at the charger with a full battery is valid (a
   free way to stand by). The heavy surcharge ``w`` does not scale with ``drain_scale``: the
   scale models a faster idle/motion drain, the surcharge the extra effort of heavy material.
2. If the battery reaches 0 the episode terminates (``battery_failure``) with penalty ``-50``.
3. Each empty zone independently produces a new material with probability ``p_spawn``
   (default 0.3), heavy with probability ``p_heavy`` (default 0.5), light otherwise. A zone
   emptied by ``load`` may refill in the same step.

Rewards (summed within a step):

=========================  =======
event                      reward
=========================  =======
every step                 ``-0.1``
deliver a heavy material   ``+10``
deliver a light material   ``+5``
invalid action             ``-1``
battery reaches 0          ``-50``
=========================  =======

A delivery cycle from a full battery at the charger costs (charger -> zone, load, -> depot,
unload, -> charger) ``5s`` for light material and ``5s + 3`` for heavy material, so with
``drain_scale=1`` both fit in one charge (5 and 8 units), while with ``drain_scale=2`` a direct
cycle (10 and 13 units) empties the battery: the robot must stop at the charger mid-delivery.

Initial state: robot at the charger, full battery, empty hands; each zone holds a material with
probability ``p_spawn`` (heavy with probability ``p_heavy``). The environment never truncates by
itself; the registered ``PackageDelivery-v0`` adds a 200-step time limit. ``info`` holds the
cumulative ``delivered_heavy`` / ``delivered_light`` counts, ``battery_failure`` and
``invalid_action``.

``render_mode="rgb_array"`` draws a 200x300 RGB image with NumPy only: the four places as
coloured squares (depot grey-blue, zone A orange, zone B green, charger yellow) with waiting
material (light = small cream square, heavy = large brown square), the robot (red disc below
its place, carrying its material), the battery bar at the bottom (green, red when <= 3) and
tally marks of delivered materials at the top.

``scripted_policy`` / ``scripted_policy_batch`` are a hand-written reference policy.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

FEATURE_NAMES: tuple[str, ...] = ("location", "battery", "carrying", "zone_a", "zone_b")
"""Names of the observation features, in vector order."""

LOCATIONS: tuple[str, ...] = ("depot", "zone_a", "zone_b", "charger")
MATERIALS: tuple[str, ...] = ("none", "light", "heavy")

FEATURE_VALUES: dict[str, tuple[str, ...]] = {
    "location": LOCATIONS,
    "carrying": MATERIALS,
    "zone_a": MATERIALS,
    "zone_b": MATERIALS,
}
"""Value labels of the categorical features (``battery`` is numeric)."""

ACTION_NAMES: tuple[str, ...] = (
    "go_depot",
    "go_zone_a",
    "go_zone_b",
    "go_charger",
    "load",
    "unload",
    "charge",
    "wait",
)
"""Names of the discrete actions, in index order."""

# Location codes.
DEPOT, ZONE_A, ZONE_B, CHARGER = 0, 1, 2, 3
# Material codes.
NONE, LIGHT, HEAVY = 0, 1, 2
# Action codes.
GO_DEPOT, GO_ZONE_A, GO_ZONE_B, GO_CHARGER, LOAD, UNLOAD, CHARGE, WAIT = range(8)
# Observation indices.
I_LOC, I_BAT, I_CARRY, I_ZA, I_ZB = range(5)

MAX_BATTERY = 10
CHARGE_RATE = 4
STEP_REWARD = -0.1
DELIVERY_REWARD = {LIGHT: 5.0, HEAVY: 10.0}
INVALID_PENALTY = -1.0
BATTERY_FAILURE_PENALTY = -50.0

OBS_NVEC = np.array([len(LOCATIONS), MAX_BATTERY + 1, 3, 3, 3], dtype=np.int64)


class PackageDeliveryEnv(gymnasium.Env):
    """Robot package-delivery domain (see the module docstring for the full specification)."""

    # a class attribute (ruff's RUF012) that gymnasium's Env annotates as an instance one
    metadata: ClassVar[dict[str, Any]] = {  # type: ignore[misc]
        "render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        p_spawn: float = 0.3,
        p_heavy: float = 0.5,
        drain_scale: int = 1,
        render_mode: str | None = None,
    ) -> None:
        if not 0.0 <= p_spawn <= 1.0 or not 0.0 <= p_heavy <= 1.0:
            raise ValueError("p_spawn and p_heavy must be probabilities")
        if int(drain_scale) != drain_scale or drain_scale < 1:
            raise ValueError(f"drain_scale must be a positive integer, got {drain_scale!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"unsupported render_mode {render_mode!r}")
        self.p_spawn = float(p_spawn)
        self.p_heavy = float(p_heavy)
        self.drain_scale = int(drain_scale)
        self.render_mode = render_mode
        self.observation_space = spaces.MultiDiscrete(OBS_NVEC.copy(), dtype=np.int64)
        self.action_space = spaces.Discrete(len(ACTION_NAMES))
        self._start_state()

    def _start_state(self) -> None:
        """Robot at the charger, full battery, empty hands and zones, nothing delivered."""
        self._loc = CHARGER
        self._battery = MAX_BATTERY
        self._carry = NONE
        self._zones = [NONE, NONE]
        self._delivered = {LIGHT: 0, HEAVY: 0}
        self._failed = False

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode at the charger with a full battery and freshly sampled zones."""
        super().reset(seed=seed)
        self._start_state()
        self._spawn()
        return self._obs(), self._info(invalid=False)

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply ``action``; return ``(obs, reward, terminated, truncated, info)``."""
        if not self.action_space.contains(action):
            raise ValueError(f"invalid action {action!r}")
        if self._failed:
            raise RuntimeError("episode is over (battery failure); call reset()")
        action = int(action)
        s = self.drain_scale
        reward = STEP_REWARD
        cost = s
        invalid = False
        carry_w = int(self._carry == HEAVY)

        if action <= GO_CHARGER:
            if action == self._loc:
                invalid = True
            else:
                self._loc = action
                cost = s + carry_w
        elif action == LOAD:
            zone = self._loc - 1 if self._loc in (ZONE_A, ZONE_B) else None
            if zone is None or self._carry != NONE or self._zones[zone] == NONE:
                invalid = True
            else:
                self._carry = self._zones[zone]
                self._zones[zone] = NONE
                cost = s + int(self._carry == HEAVY)
        elif action == UNLOAD:
            if self._loc != DEPOT or self._carry == NONE:
                invalid = True
            else:
                reward += DELIVERY_REWARD[self._carry]
                self._delivered[self._carry] += 1
                self._carry = NONE
                cost = s + carry_w
        elif action == CHARGE:
            if self._loc != CHARGER:
                invalid = True
            else:
                cost = 0
                self._battery = min(MAX_BATTERY, self._battery + CHARGE_RATE)
        # WAIT: cost s, nothing else.

        if invalid:
            reward += INVALID_PENALTY
        self._battery = max(0, self._battery - cost)
        terminated = self._battery == 0
        if terminated:
            self._failed = True
            reward += BATTERY_FAILURE_PENALTY
        self._spawn()
        return self._obs(), float(reward), bool(terminated), False, self._info(invalid)

    def render(self) -> np.ndarray | None:
        """Return an ``HxWx3`` uint8 image when ``render_mode == "rgb_array"``, else ``None``."""
        if self.render_mode != "rgb_array":
            return None
        return render_state(self._obs(), self._delivered[HEAVY], self._delivered[LIGHT])

    # ------------------------------------------------------------------ helpers
    def _spawn(self) -> None:
        """Each empty zone produces a material with probability ``p_spawn``."""
        for z in range(2):
            # Always draw both numbers so the RNG stream does not depend on the state.
            u_spawn, u_heavy = self.np_random.random(2)
            if self._zones[z] == NONE and u_spawn < self.p_spawn:
                self._zones[z] = HEAVY if u_heavy < self.p_heavy else LIGHT

    def _obs(self) -> np.ndarray:
        return np.array(
            [self._loc, self._battery, self._carry, self._zones[0], self._zones[1]],
            dtype=np.int64,
        )

    def _info(self, invalid: bool) -> dict[str, Any]:
        return {
            "delivered_heavy": self._delivered[HEAVY],
            "delivered_light": self._delivered[LIGHT],
            "battery_failure": self._failed,
            "invalid_action": invalid,
        }


# ---------------------------------------------------------------------- rendering
_H, _W = 200, 300
_SQ, _GAP, _TOP = 60, 12, 40
_PLACE_COLORS = {
    DEPOT: (110, 130, 160),
    ZONE_A: (235, 150, 60),
    ZONE_B: (90, 175, 95),
    CHARGER: (235, 210, 60),
}
_MATERIAL_STYLE = {LIGHT: (12, (250, 240, 200)), HEAVY: (26, (110, 60, 25))}


def _place_x(loc: int) -> int:
    return _GAP + loc * (_SQ + _GAP)


def _fill(img: np.ndarray, y0: int, y1: int, x0: int, x1: int, color: tuple[int, ...]) -> None:
    img[max(y0, 0) : min(y1, _H), max(x0, 0) : min(x1, _W)] = color


def _material(img: np.ndarray, cy: int, cx: int, material: int) -> None:
    if material == NONE:
        return
    size, color = _MATERIAL_STYLE[material]
    h = size // 2
    _fill(img, cy - h - 1, cy + h + 1, cx - h - 1, cx + h + 1, (30, 30, 30))
    _fill(img, cy - h, cy + h, cx - h, cx + h, color)


def render_layout() -> dict[str, tuple[int, int]]:
    """Where :func:`render_state` draws each place and the battery bar: name -> pixel (x, y)
    at which a figure can label it (the lower part of each place's square)."""
    spots = {name: (_place_x(loc) + _SQ // 2, _TOP + _SQ - 10)
             for loc, name in enumerate(LOCATIONS)}
    spots["battery"] = (_W // 2, 181)
    return spots


def render_state(obs: np.ndarray, delivered_heavy: int = 0, delivered_light: int = 0) -> np.ndarray:
    """Draw an observation (plus delivery tallies) as a ``200x300x3`` uint8 image."""
    loc, battery, carry, za, zb = (int(v) for v in np.asarray(obs).reshape(-1)[:5])
    img = np.full((_H, _W, 3), 245, dtype=np.uint8)
    # Delivered tallies: heavy (brown, tall) then light (cream, short).
    x = _GAP
    tallies = ((delivered_heavy, 16, (110, 60, 25)), (delivered_light, 10, (200, 180, 120)))
    for count, h, color in tallies:
        for _ in range(count):
            if x + 3 > _W - _GAP:
                break
            _fill(img, 28 - h, 28, x, x + 3, color)
            x += 5
        x += 6
    # Places with waiting material.
    for place, color in _PLACE_COLORS.items():
        x0 = _place_x(place)
        _fill(img, _TOP - 2, _TOP + _SQ + 2, x0 - 2, x0 + _SQ + 2, (40, 40, 40))
        _fill(img, _TOP, _TOP + _SQ, x0, x0 + _SQ, color)
    cy = _TOP + _SQ // 2
    _material(img, cy, _place_x(ZONE_A) + _SQ // 2, za)
    _material(img, cy, _place_x(ZONE_B) + _SQ // 2, zb)
    # Charger bolt: a dark diagonal stripe.
    x0 = _place_x(CHARGER)
    for i in range(30):
        _fill(img, _TOP + 15 + i, _TOP + 16 + i, x0 + 38 - i // 2, x0 + 44 - i // 2, (60, 60, 60))
    # Robot: red disc below its place, carried material on top of it.
    rcx, rcy, r = _place_x(loc) + _SQ // 2, _TOP + _SQ + 30, 18
    yy, xx = np.ogrid[:_H, :_W]
    disc = (yy - rcy) ** 2 + (xx - rcx) ** 2
    img[disc <= (r + 2) ** 2] = (40, 40, 40)
    img[disc <= r**2] = (210, 40, 40)
    _material(img, rcy, rcx, carry)
    # Battery bar.
    y0, y1, bx0, bx1 = 172, 190, _GAP, _W - _GAP
    _fill(img, y0 - 2, y1 + 2, bx0 - 2, bx1 + 2, (40, 40, 40))
    _fill(img, y0, y1, bx0, bx1, (255, 255, 255))
    level = max(0, min(battery, MAX_BATTERY))
    bar_color = (60, 180, 70) if level > 3 else (220, 50, 50)
    _fill(img, y0, y1, bx0, bx0 + (bx1 - bx0) * level // MAX_BATTERY, bar_color)
    for k in range(1, MAX_BATTERY):
        xk = bx0 + (bx1 - bx0) * k // MAX_BATTERY
        _fill(img, y0, y1, xk, xk + 1, (150, 150, 150))
    return img


# ---------------------------------------------------------------------- scripted policy
def _cost(drain_scale: int, material: int) -> int:
    """Battery cost of a move / load / unload with ``material`` carried or handled."""
    return drain_scale + int(material == HEAVY)


def _can_deliver(loc: int, battery: int, material: int, s: int) -> tuple[bool, bool]:
    """Whether a robot carrying ``material`` can deliver it and get back to the charger.

    Returns ``(direct, via_charger)``: ``direct`` when going to the depot (unless there),
    unloading and moving to the charger leaves a positive battery; ``via_charger`` when it can
    reach the charger alive and, from a full battery there, do the direct trip.
    """
    c = _cost(s, material)
    direct = (0 if loc == DEPOT else c) + c + s < battery
    via = (loc == CHARGER or c < battery) and c + c + s < MAX_BATTERY
    return direct, via


def scripted_policy(obs: np.ndarray, drain_scale: int = 1) -> int:
    """Hand-written reference policy for one observation (``drain_scale`` as the env's).

    Deliver what is carried (stopping at the charger first if the battery would not last);
    otherwise fetch a waiting material (heavy first, then the one at the robot's zone, then
    zone A) whose whole delivery the battery allows, charging first when it does not; with
    nothing to fetch, go to the charger and stand by charging.
    """
    loc, battery, carry, za, zb = (int(v) for v in np.asarray(obs).reshape(-1)[:5])
    s = int(drain_scale)

    if carry != NONE:
        c = _cost(s, carry)
        if loc == DEPOT:
            if c + s < battery or c >= battery:  # safe, or hopeless either way
                return UNLOAD
            return GO_CHARGER
        direct, _ = _can_deliver(loc, battery, carry, s)
        if direct:
            return GO_DEPOT
        if loc == CHARGER:
            return CHARGE if battery < MAX_BATTERY else GO_DEPOT
        return GO_CHARGER if c < battery else GO_DEPOT

    waiting = [(z, m) for z, m in ((ZONE_A, za), (ZONE_B, zb)) if m != NONE]
    waiting.sort(key=lambda zm: (zm[1] != HEAVY, zm[0] != loc, zm[0]))
    for zone, material in waiting:
        handle = _cost(s, material)
        # Feasible at all (from a full battery at the charger)?
        if not (
            s + handle < MAX_BATTERY
            and any(_can_deliver(zone, MAX_BATTERY - s - handle, material, s))
        ):
            continue
        reach = 0 if loc == zone else s
        after = battery - reach - handle
        direct, via = _can_deliver(zone, after, material, s) if after > 0 else (False, False)
        if loc == CHARGER and battery < MAX_BATTERY and not direct:
            return CHARGE  # top up rather than detour later
        if direct or via:
            return LOAD if loc == zone else zone
        return CHARGE if loc == CHARGER else GO_CHARGER
    return CHARGE if loc == CHARGER else GO_CHARGER


@lru_cache(maxsize=8)
def _policy_table(drain_scale: int) -> np.ndarray:
    """``scripted_policy`` tabulated over every observation (raveled MultiDiscrete index)."""
    table = np.empty(int(np.prod(OBS_NVEC)), dtype=np.int64)
    for i, obs in enumerate(np.ndindex(*OBS_NVEC)):
        table[i] = scripted_policy(np.array(obs), drain_scale)
    table.setflags(write=False)
    return table


def scripted_policy_batch(obs_batch: np.ndarray, drain_scale: int = 1) -> np.ndarray:
    """Vectorised ``scripted_policy`` for an ``(n, 5)`` batch; returns ``(n,)`` int64 actions."""
    obs_batch = np.asarray(obs_batch, dtype=np.int64)
    if obs_batch.ndim == 1:
        obs_batch = obs_batch[None, :]
    idx = np.ravel_multi_index(tuple(obs_batch[:, :5].T), tuple(OBS_NVEC))
    return _policy_table(int(drain_scale))[idx].copy()
