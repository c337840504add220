"""A misbehaving environment stops a rollout with one ``EnvError`` of one line that names the
environment, the call, the episode's seed and step, the fault and its fix (in-process: the
command-line runs of the same environments are in ``tests/test_hostile_env.py``)."""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pytest

import tests.fixtures.hostile_envs as hostile
from ibt.evaluate.rollouts import EnvError, _bad_answer, _bad_obs, _raised, rollout
from ibt.tasks.catalogue import resolve_task

LEFT = staticmethod(lambda obs: np.zeros(len(obs), dtype=np.int64))


@pytest.mark.parametrize(("fault", "message"), [
    ("raising_reset", "failed in reset() (reset of the episode with seed 5): it raised "
     "ValueError: the simulator's licence server is unreachable; fix its reset()"),
    ("raising_step", "failed in step() (step 3 of the episode with seed 5): it raised "
     "RuntimeError: joint 2 exceeded its torque limit (action 0); fix its step()"),
    ("nan_reward", "failed in step() (step 3 of the episode with seed 5): it returned the "
     "reward nan; return finite rewards"),
    ("inf_reward", "failed in step() (step 2 of the episode with seed 5): the rewards summed "
     "to inf (this reward: 1e+308); scale the reward down so that an episode's return stays "
     "finite"),
    ("inf_observation", "failed in step() (step 2 of the episode with seed 5): it returned a "
     "non-finite observation (x1=inf); make its step() return finite observations"),
    ("wrong_shape", "failed in reset() (reset of the episode with seed 5): it returned an "
     "observation of shape (3,), but its observation_space has shape (2,); make its reset() "
     "return observations of its observation_space"),
])
def test_each_fault_is_one_line_naming_call_seed_step_and_fix(fault, message):
    task = resolve_task(hostile.ENV_IDS[fault])
    with pytest.raises(EnvError) as caught:
        rollout(task, LEFT, [5, 6], n_envs=2)
    assert str(caught.value) == f"the environment {task.gym_id} {message}"


def test_a_fine_environment_runs_every_episode_to_its_end():
    result = rollout(resolve_task(hostile.ENV_IDS["fine"]), LEFT, [5, 6, 7], n_envs=2)
    assert result.lengths.tolist() == [hostile.STEPS] * 3
    assert np.all(np.isfinite(result.returns)) and not result.terminated.any()


class Answering(hostile.Hostile):
    """The fine task whose ``step`` answers with a reward that is not a number from step 2 on."""

    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, kind: str = "fine") -> None:
        super().__init__("fine")
        self.kind = kind

    def step(self, action: Any):
        answer = super().step(action)
        if self.t < 2:
            return answer
        return (answer[0], "much", *answer[2:]) if self.kind == "text_reward" else answer


if "Test-Answering-v0" not in gym.registry:
    gym.register(id="Test-Answering-v0", entry_point=Answering, max_episode_steps=hostile.STEPS)


def test_a_reward_that_is_not_a_number_is_named():
    """gymnasium's TimeLimit, which wraps every rollout's environment, unpacks a step's answer
    itself, so only the reward's form reaches ``_bad_answer`` through a rollout."""
    from dataclasses import replace

    task = replace(resolve_task(hostile.ENV_IDS["fine"]), gym_id="Test-Answering-v0")
    with pytest.raises(EnvError, match=r"failed in step\(\) \(step 2 of the episode with seed "
                                       r"9\): it returned a reward 'much' that is not a number"):
        rollout(task, LEFT, [9], env_kwargs={"kind": "text_reward"})


@pytest.mark.parametrize(("answer", "problem"), [
    ((0, 1.0, False, False), "it returned 4 values, not gymnasium's 5"),
    ([0, 1.0, False, False, {}], "it returned list, not gymnasium's 5"),
    ((0, 1.0, False, False, {}, 0), "it returned 6 values, not gymnasium's 5"),
    ((0, "much", False, False, {}), "it returned a reward 'much' that is not a number"),
])
def test_a_step_answer_out_of_form_is_named(answer, problem):
    """Mutants: ``_bad_answer``'s test of the tuple's form inverted or its count changed."""
    assert _bad_answer(answer) == problem


def test_an_error_message_is_kept_on_one_line_and_cut_at_160_characters():
    """Mutants: the limit or the cut of ``_raised`` changed."""
    assert _raised(ValueError("")) == "it raised ValueError"
    assert _raised(RuntimeError("a\n  b")) == "it raised RuntimeError: a b"
    exact = "x" * 160
    assert _raised(RuntimeError(exact)) == f"it raised RuntimeError: {exact}"
    long = _raised(RuntimeError("y" * 161))
    assert long == "it raised RuntimeError: " + "y" * 157 + "..."


def test_an_observation_is_judged_by_its_shape_its_numbers_and_their_finiteness():
    """Mutants: the shape test, the dtype test or the non-finite listing of ``_bad_obs``."""
    task = resolve_task(hostile.ENV_IDS["fine"])
    assert _bad_obs(task, np.zeros(2), (2,)) is None
    assert _bad_obs(task, np.zeros(2), None) is None
    assert _bad_obs(task, np.zeros(3), (2,)) == (
        "it returned an observation of shape (3,), but its observation_space has shape (2,)")
    assert _bad_obs(task, np.array(["a", "b"]), (2,)) == (
        "it returned an observation of dtype <U1, not numbers")
    assert _bad_obs(task, np.array([np.nan, np.inf]), (2,)) == (
        "it returned a non-finite observation (x0=nan, x1=inf)")
    assert _bad_obs(task, np.array([1.0, 2.0, np.inf, np.nan, np.inf, -np.inf]), None) == (
        "it returned a non-finite observation (2=inf, 3=nan, 4=inf)")  # the first three, and
    # unnamed past the task's names
