"""Tests of the package-delivery environment and its scripted reference policy."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import ibt.envs
from ibt.envs import package_delivery as pd
from ibt.envs.package_delivery import (
    ACTION_NAMES,
    FEATURE_NAMES,
    FEATURE_VALUES,
    PackageDeliveryEnv,
    scripted_policy,
    scripted_policy_batch,
)

A = {name: i for i, name in enumerate(ACTION_NAMES)}


def make_state(
    env: PackageDeliveryEnv,
    *,
    loc: int = pd.CHARGER,
    battery: int = pd.MAX_BATTERY,
    carry: int = pd.NONE,
    zones: tuple[int, int] = (pd.NONE, pd.NONE),
) -> None:
    """Put a reset env into a chosen state (white-box, for unit tests of the dynamics)."""
    env._loc, env._battery, env._carry, env._zones = loc, battery, carry, list(zones)


@pytest.fixture
def env() -> PackageDeliveryEnv:
    e = PackageDeliveryEnv(p_spawn=0.0)  # no spawning: zone contents are fully controlled
    e.reset(seed=0)
    return e


def run_episode(seed: int, policy: str, drain_scale: int = 1) -> tuple[float, dict]:
    env = gymnasium.make("PackageDelivery-v0", drain_scale=drain_scale)
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    total = 0.0
    while True:
        if policy == "scripted":
            action = scripted_policy(obs, drain_scale)
        else:
            action = env.action_space.sample()
        obs, reward, terminated, truncated, info = env.step(action)
        total += reward
        if terminated or truncated:
            return total, info


def test_constants_and_spaces() -> None:
    env = PackageDeliveryEnv()
    assert FEATURE_NAMES == ("location", "battery", "carrying", "zone_a", "zone_b")
    assert FEATURE_VALUES["carrying"] == ("none", "light", "heavy")
    assert FEATURE_VALUES["location"] == ("depot", "zone_a", "zone_b", "charger")
    assert len(ACTION_NAMES) == env.action_space.n == 8
    assert env.observation_space.shape == (len(FEATURE_NAMES),)
    assert env.observation_space.dtype == np.int64
    obs, _ = env.reset(seed=1)
    assert obs.dtype == np.int64 and env.observation_space.contains(obs)
    assert obs[pd.I_LOC] == pd.CHARGER
    assert obs[pd.I_BAT] == pd.MAX_BATTERY
    assert obs[pd.I_CARRY] == pd.NONE


@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_check_env_passes(render_mode: str | None) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gymnasium.make("PackageDelivery-v0", render_mode=render_mode)
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []


def test_registration_is_idempotent() -> None:
    import importlib

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        importlib.reload(ibt.envs)
    env = gymnasium.make("PackageDelivery-v0")
    assert env.spec is not None and env.spec.max_episode_steps == 200
    assert isinstance(env.unwrapped, PackageDeliveryEnv)


def _trajectory(seed: int, actions: np.ndarray) -> tuple[list, list]:
    env = PackageDeliveryEnv()
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for a in actions:
        obs, r, terminated, _, _ = env.step(int(a))
        observations.append(obs)
        rewards.append(r)
        if terminated:
            obs, _ = env.reset()
            observations.append(obs)
    return observations, rewards


def test_determinism_under_seed() -> None:
    actions = np.random.default_rng(7).integers(0, 8, size=300)
    obs1, rew1 = _trajectory(42, actions)
    obs2, rew2 = _trajectory(42, actions)
    assert len(obs1) == len(obs2)
    assert all(np.array_equal(a, b) for a, b in zip(obs1, obs2, strict=True))
    assert rew1 == rew2
    obs3, _ = _trajectory(43, actions)
    assert len(obs1) != len(obs3) or any(
        not np.array_equal(a, b) for a, b in zip(obs1, obs3, strict=True)
    )


def test_move_drains_battery_more_when_carrying_heavy(env: PackageDeliveryEnv) -> None:
    obs, *_ = env.step(A["go_depot"])
    assert obs[pd.I_LOC] == pd.DEPOT and obs[pd.I_BAT] == 9
    make_state(env, loc=pd.ZONE_A, battery=8, carry=pd.LIGHT)
    obs, *_ = env.step(A["go_depot"])
    assert obs[pd.I_BAT] == 7
    make_state(env, loc=pd.ZONE_A, battery=8, carry=pd.HEAVY)
    obs, *_ = env.step(A["go_depot"])
    assert obs[pd.I_BAT] == 6 and obs[pd.I_CARRY] == pd.HEAVY


def test_drain_scale_multiplies_base_cost() -> None:
    env = PackageDeliveryEnv(p_spawn=0.0, drain_scale=2)
    env.reset(seed=0)
    obs, *_ = env.step(A["go_zone_b"])
    assert obs[pd.I_BAT] == 8
    obs, *_ = env.step(A["wait"])
    assert obs[pd.I_BAT] == 6
    make_state(env, loc=pd.ZONE_B, battery=8, carry=pd.HEAVY)
    obs, *_ = env.step(A["go_depot"])
    assert obs[pd.I_BAT] == 5  # 2 * 1 + heavy surcharge 1


def test_load_and_unload(env: PackageDeliveryEnv) -> None:
    make_state(env, loc=pd.ZONE_A, battery=10, zones=(pd.HEAVY, pd.LIGHT))
    obs, r, *_ = env.step(A["load"])
    assert obs[pd.I_CARRY] == pd.HEAVY and obs[pd.I_ZA] == pd.NONE and obs[pd.I_ZB] == pd.LIGHT
    assert obs[pd.I_BAT] == 8 and r == pytest.approx(-0.1)
    make_state(env, loc=pd.ZONE_B, battery=10, zones=(pd.NONE, pd.LIGHT))
    obs, *_ = env.step(A["load"])
    assert obs[pd.I_CARRY] == pd.LIGHT and obs[pd.I_BAT] == 9


def test_delivery_rewards_and_counters(env: PackageDeliveryEnv) -> None:
    make_state(env, loc=pd.DEPOT, battery=10, carry=pd.HEAVY)
    obs, r_heavy, _, _, info = env.step(A["unload"])
    assert obs[pd.I_CARRY] == pd.NONE and obs[pd.I_BAT] == 8
    assert (info["delivered_heavy"], info["delivered_light"]) == (1, 0)
    make_state(env, loc=pd.DEPOT, battery=10, carry=pd.LIGHT)
    obs, r_light, _, _, info = env.step(A["unload"])
    assert obs[pd.I_BAT] == 9
    assert (info["delivered_heavy"], info["delivered_light"]) == (1, 1)
    assert r_heavy == pytest.approx(10 - 0.1)
    assert r_light == pytest.approx(5 - 0.1)
    assert r_heavy > r_light
    make_state(env, loc=pd.DEPOT, battery=10, carry=pd.HEAVY)
    *_, info = env.step(A["unload"])
    assert (info["delivered_heavy"], info["delivered_light"]) == (2, 1)
    env.reset(seed=1)
    *_, info = env.step(A["wait"])
    assert (info["delivered_heavy"], info["delivered_light"]) == (0, 0)


def test_empty_battery_terminates_with_penalty(env: PackageDeliveryEnv) -> None:
    make_state(env, loc=pd.ZONE_A, battery=2, carry=pd.HEAVY)
    obs, r, terminated, truncated, info = env.step(A["go_depot"])
    assert terminated and not truncated
    assert obs[pd.I_BAT] == 0
    assert info["battery_failure"] is True
    assert r == pytest.approx(-50 - 0.1)
    with pytest.raises(RuntimeError):
        env.step(A["wait"])


def test_no_failure_while_battery_positive(env: PackageDeliveryEnv) -> None:
    make_state(env, loc=pd.ZONE_A, battery=3, carry=pd.HEAVY)
    _, r, terminated, _, info = env.step(A["go_depot"])
    assert not terminated and info["battery_failure"] is False and r > -1


@pytest.mark.parametrize(
    ("loc", "carry", "zones", "action"),
    [
        (pd.DEPOT, pd.NONE, (pd.HEAVY, pd.HEAVY), "load"),  # not at a zone
        (pd.ZONE_A, pd.NONE, (pd.NONE, pd.HEAVY), "load"),  # nothing waiting here
        (pd.ZONE_A, pd.LIGHT, (pd.HEAVY, pd.NONE), "load"),  # hands full
        (pd.ZONE_B, pd.HEAVY, (pd.NONE, pd.NONE), "unload"),  # not at the depot
        (pd.DEPOT, pd.NONE, (pd.NONE, pd.NONE), "unload"),  # nothing carried
        (pd.DEPOT, pd.NONE, (pd.NONE, pd.NONE), "charge"),  # not at the charger
        (pd.DEPOT, pd.NONE, (pd.NONE, pd.NONE), "go_depot"),  # already there
    ],
)
def test_invalid_action_penalty(
    env: PackageDeliveryEnv, loc: int, carry: int, zones: tuple[int, int], action: str
) -> None:
    make_state(env, loc=loc, battery=7, carry=carry, zones=zones)
    before = env._obs()
    obs, r, terminated, _, info = env.step(A[action])
    assert r == pytest.approx(-1 - 0.1)
    assert info["invalid_action"] is True and not terminated
    expected = before.copy()
    expected[pd.I_BAT] -= 1  # only the base time cost
    np.testing.assert_array_equal(obs, expected)


def test_wait_is_valid_and_costs_time(env: PackageDeliveryEnv) -> None:
    make_state(env, loc=pd.ZONE_B, battery=5)
    obs, r, _, _, info = env.step(A["wait"])
    assert obs[pd.I_BAT] == 4 and r == pytest.approx(-0.1) and not info["invalid_action"]


def test_charge_restores_battery_capped(env: PackageDeliveryEnv) -> None:
    make_state(env, loc=pd.CHARGER, battery=3)
    obs, r, *_ = env.step(A["charge"])
    assert obs[pd.I_BAT] == 7 and r == pytest.approx(-0.1)
    obs, *_ = env.step(A["charge"])
    assert obs[pd.I_BAT] == pd.MAX_BATTERY
    obs, _, _, _, info = env.step(A["charge"])
    assert obs[pd.I_BAT] == pd.MAX_BATTERY and not info["invalid_action"]


def test_spawning_probabilities() -> None:
    never = PackageDeliveryEnv(p_spawn=0.0)
    obs, _ = never.reset(seed=0)
    for _ in range(20):
        obs, *_ = never.step(A["charge"])
        assert obs[pd.I_ZA] == obs[pd.I_ZB] == pd.NONE
    always_light = PackageDeliveryEnv(p_spawn=1.0, p_heavy=0.0)
    obs, _ = always_light.reset(seed=0)
    assert obs[pd.I_ZA] == obs[pd.I_ZB] == pd.LIGHT
    always_heavy = PackageDeliveryEnv(p_spawn=1.0, p_heavy=1.0)
    always_heavy.reset(seed=0)
    always_heavy.step(A["go_zone_a"])
    obs, *_ = always_heavy.step(A["load"])
    assert obs[pd.I_CARRY] == pd.HEAVY and obs[pd.I_ZA] == pd.HEAVY  # refilled at once


def test_rgb_render() -> None:
    env = PackageDeliveryEnv(render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert isinstance(img, np.ndarray)
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8
    assert img.shape[:2] == (200, 300)
    env.step(A["go_depot"])
    assert not np.array_equal(env.render(), img)  # the robot and battery bar moved
    assert PackageDeliveryEnv().render() is None


def test_scripted_batch_matches_single() -> None:
    all_obs = np.array(list(np.ndindex(*pd.OBS_NVEC)), dtype=np.int64)
    for scale in (1, 2):
        batch = scripted_policy_batch(all_obs, scale)
        assert batch.shape == (len(all_obs),)
        single = np.array([scripted_policy(o, scale) for o in all_obs[::7]])
        np.testing.assert_array_equal(batch[::7], single)
    assert scripted_policy_batch(all_obs[0])[0] == scripted_policy(all_obs[0])


@pytest.mark.parametrize("drain_scale", [1, 2])
def test_scripted_beats_random_and_never_fails(drain_scale: int) -> None:
    scripted, random = [], []
    for seed in range(20):
        ret, info = run_episode(seed, "scripted", drain_scale)
        assert not info["battery_failure"], f"scripted policy ran out of battery (seed {seed})"
        assert info["delivered_heavy"] > 0 and info["delivered_light"] >= 0
        scripted.append(ret)
        random.append(run_episode(seed, "random", drain_scale)[0])
    assert np.mean(scripted) > 100
    assert np.mean(scripted) > np.mean(random) + 100
