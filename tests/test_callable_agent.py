"""An agent given as ``MODULE:FUNCTION``: loading, answers checked, weights, digest, every error
path (one line naming the spec), and real distillations imitating a hand-written rule."""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.distill.continuous import BoxDistillConfig, box_tree_policy, distill_box
from ibt.distill.loop import DistillConfig, distill, learner_policy, tree_signature
from ibt.evaluate.policies import CompiledTree
from ibt.evaluate.rollouts import rollout
from ibt.experts.callable_agent import (
    PROB_FLOOR,
    CallableExpert,
    agent_digest,
    load_callable_agent,
)
from ibt.experts.expert import Expert
from ibt.tasks.catalogue import get_task

CARTPOLE = get_task("CartPole-v1")
PENDULUM = get_task("Pendulum-v1")
RULE = """
import numpy as np

def act(obs):
    return 1 if obs[2] + 0.1 * obs[3] > 0 else 0
"""
OBS = np.array([[0.0, 0.0, 0.05, 0.0], [0.0, 0.0, -0.05, 0.0], [0.1, 0.2, 0.01, -0.3]],
               dtype=np.float32)
RULE_ACTIONS = [1, 0, 0]


def write(folder, text, name="agent.py"):
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


def rule(obs):
    return (obs[:, 2] + 0.1 * obs[:, 3] > 0).astype(np.int64)


def test_a_plain_rule_acts_with_uniform_weights_and_has_no_scores(tmp_path):
    agent = load_callable_agent(CARTPOLE, f"{write(tmp_path, RULE)}:act")
    assert isinstance(agent, CallableExpert) and isinstance(agent, Expert)
    assert (agent.algo, agent.continuous, agent.n_actions) == ("callable", False, 2)
    actions = agent.act(OBS)
    assert actions.dtype == np.int64 and actions.tolist() == RULE_ACTIONS
    labels, weights = agent.label(OBS)
    assert labels.tolist() == RULE_ACTIONS and weights.tolist() == [1.0, 1.0, 1.0]
    with pytest.raises(TypeError, match="no per-action scores"):
        agent.scores(OBS)
    with pytest.raises(TypeError, match="no critic"):
        agent.action_loss(OBS, np.zeros(3))


def test_q_values_give_the_dqn_weights(tmp_path):
    path = write(tmp_path, RULE + """
def q(obs):
    s = obs[2] + 0.1 * obs[3]
    return [-s, s]

act.q_values = q
""")
    agent = load_callable_agent(CARTPOLE, f"{path}:act")
    scores = agent.scores(OBS)
    s = OBS[:, 2].astype(np.float64) + 0.1 * OBS[:, 3]
    assert scores.shape == (3, 2) and np.allclose(scores, np.stack([-s, s], axis=1))
    actions, weights = agent.label(OBS)
    assert actions.tolist() == RULE_ACTIONS and np.allclose(weights, 2 * np.abs(s))


def test_probabilities_give_the_ppo_weights_and_batched_agents_answer_at_once(tmp_path):
    path = write(tmp_path, """
import numpy as np

def act(obs):
    return np.argmax(probs(obs), axis=1)

def probs(obs):
    return np.stack([1 - obs[:, 0], obs[:, 0]], axis=1)

act.batched = True
act.action_probabilities = probs
""")
    agent = load_callable_agent(CARTPOLE, f"{path}:act")
    obs = np.array([[0.2, 0, 0, 0], [0.9, 0, 0, 0], [1.0, 0, 0, 0]], dtype=np.float32)
    actions, weights = agent.label(obs)
    assert actions.tolist() == [0, 1, 1]
    expected = [np.log(0.8 / 0.2), np.log(0.9 / np.float32(1 - np.float32(0.9))),
                -np.log(PROB_FLOOR)]  # p = 0 is floored: a finite weight
    assert np.allclose(weights, expected, rtol=1e-5)
    assert np.allclose(np.exp(agent.scores(obs[:2])).sum(axis=1), 1.0)


def test_a_callable_object_in_an_importable_module(tmp_path, monkeypatch):
    package = tmp_path / "myagents"
    package.mkdir()
    (package / "__init__.py").write_text("")
    write(package, """
class Agent:
    def __call__(self, obs):
        return int(obs[2] > 0)

    def q_values(self, obs):
        return [0.0, 3.0 * float(obs[2])]

pilot = Agent()
""", name="rules.py")
    monkeypatch.syspath_prepend(str(tmp_path))
    agent = load_callable_agent(CARTPOLE, "myagents.rules:pilot")
    assert agent.act(OBS).tolist() == [1, 0, 1]
    assert np.allclose(agent.label(OBS)[1], 3.0 * np.abs(OBS[:, 2]))
    # the same source read as a file is the same agent
    assert agent_digest("myagents.rules:pilot") == agent_digest(f"{package / 'rules.py'}:pilot")


def test_a_file_may_import_its_neighbours_and_leaves_sys_path_alone(tmp_path):
    write(tmp_path, "THRESHOLD = 0.0\n", name="agent_helpers.py")
    path = write(tmp_path, """
from agent_helpers import THRESHOLD

def act(obs):
    return int(obs[2] > THRESHOLD)
""")
    before = list(sys.path)
    assert load_callable_agent(CARTPOLE, f"{path}:act").act(OBS).tolist() == [1, 0, 1]
    assert sys.path == before


def test_an_edited_file_is_loaded_again_and_changes_the_digest(tmp_path):
    path = write(tmp_path, RULE)
    spec = f"{path}:act"
    first = agent_digest(spec)
    assert agent_digest(spec) == first and len(first) == 64
    assert agent_digest(f"{path}:other") != first  # the function is part of the identity
    assert load_callable_agent(CARTPOLE, spec).act(OBS).tolist() == RULE_ACTIONS
    write(tmp_path, "def act(obs):\n    return 0  # always left\n")
    assert load_callable_agent(CARTPOLE, spec).act(OBS).tolist() == [0, 0, 0]
    assert agent_digest(spec) != first


def test_box_agents_answer_vectors_clipped_to_the_box(tmp_path):
    path = write(tmp_path, """
import numpy as np

def torque(obs):
    return -2.0 * obs[1] - 0.5 * obs[2]  # a plain number: the Box has one dimension

def vector(obs):
    return np.array([10.0])
""")
    agent = load_callable_agent(PENDULUM, f"{path}:torque")
    obs = np.array([[1.0, 0.5, 0.2], [1.0, -0.1, 9.0]], dtype=np.float32)
    actions, weights = agent.label(obs)
    assert actions.dtype == np.float32 and actions.shape == (2, 1)
    assert np.allclose(actions[:, 0], [-1.1, -2.0])  # -4.3 clipped to the Box's -2
    assert weights.tolist() == [1.0, 1.0]
    assert load_callable_agent(PENDULUM, f"{path}:vector").act(obs).tolist() == [[2.0], [2.0]]


def _one_line_naming(err: pytest.ExceptionInfo, spec: str) -> None:
    text = str(err.value)
    assert "\n" not in text and repr(spec) in text, text


LOAD_ERRORS = [  # (module source or None, spec tail, error type, words of the message)
    (None, "agent.py", ValueError, "not MODULE:FUNCTION"),
    (RULE, "agent.py:act()", ValueError, "is not MODULE:FUNCTION"),
    (None, "missing.py:act", FileNotFoundError, "is missing"),
    (None, "", ValueError, "is not a file"),  # the folder itself
    ("import numpy\nraise RuntimeError('no model\\nfile')\n", "agent.py:act", ValueError,
     "RuntimeError: no model file"),
    ("import sys\nsys.exit(3)\n", "agent.py:act", ValueError, "SystemExit"),
    ("def act(x:\n", "agent.py:act", ValueError, "SyntaxError"),
    ("import no_such_package_here\n", "agent.py:act", ValueError, "ModuleNotFoundError"),
    (RULE, "agent.py:acts", ValueError, "has no attribute 'acts'"),
    (RULE, "agent.py:act.inner.deeper", ValueError, "has no attribute 'inner'"),
    ("act = 3\n", "agent.py:act", ValueError, "is a int, not a callable"),
    (RULE + "act.q_values = act\nact.action_probabilities = act\n", "agent.py:act", ValueError,
     "give at most one"),
    (RULE + "act.q_values = 'high'\n", "agent.py:act", ValueError, "a callable of the obs"),
]


@pytest.mark.parametrize(("source", "tail", "kind", "words"), LOAD_ERRORS)
def test_every_load_failure_is_one_line_naming_the_spec(tmp_path, source, tail, kind, words):
    if source is not None:
        write(tmp_path, source)
    spec = f"{tmp_path}/{tail}" if tail else f"{tmp_path}:act"
    with pytest.raises(kind, match=words.replace("(", r"\(").replace(")", r"\)")) as err:
        load_callable_agent(CARTPOLE, spec)
    _one_line_naming(err, spec)


def test_module_names_that_do_not_import_are_one_line(tmp_path):
    for spec, words in (("no_such_agent_module:act", "No module named"),
                        ("not a module!:act", "is not MODULE:FUNCTION"),
                        (".:act", "is not MODULE:FUNCTION")):
        with pytest.raises(ValueError, match=words) as err:
            load_callable_agent(CARTPOLE, spec)
        _one_line_naming(err, spec)
    with pytest.raises(ValueError, match="no module named"):
        agent_digest("no_such_agent_module:act")
    with pytest.raises(FileNotFoundError, match="is missing"):
        agent_digest(f"{tmp_path}/missing.py:act")


def test_companions_are_refused_on_a_box_task(tmp_path):
    spec = f"{write(tmp_path, RULE + 'act.q_values = act' + chr(10))}:act"
    with pytest.raises(ValueError, match="none on a Box task") as err:
        load_callable_agent(PENDULUM, spec)
    _one_line_naming(err, spec)


BAD_ANSWERS = [  # (task, body answering observation 1 badly, words of the message)
    (CARTPOLE, "return 1.0", "an integer action in 0..1"),
    (CARTPOLE, "return True", "an integer action"),
    (CARTPOLE, "return 2", "an integer action in 0..1"),
    (CARTPOLE, "return [0, 1]", "an integer action"),
    (CARTPOLE, "return None", "an integer action"),
    (CARTPOLE, "raise KeyError('stuck')", "raised KeyError"),
    (PENDULUM, "return [0.0, 1.0]", "a finite action vector of 1"),
    (PENDULUM, "return float('nan')", "a finite action vector"),
    (PENDULUM, "return 'left'", "a finite action vector"),
]


@pytest.mark.parametrize(("task", "body", "words"), BAD_ANSWERS)
def test_bad_answers_name_the_spec_and_the_observation(tmp_path, task, body, words):
    good = "np.zeros(1)" if task.continuous else "0"
    path = write(tmp_path, f"""
import numpy as np
CALLS = []

def act(obs):
    CALLS.append(1)
    if len(CALLS) == 2:
        {body}
    return {good}
""")
    spec = f"{path}:act"
    agent = load_callable_agent(task, spec)
    with pytest.raises(ValueError, match=words) as err:
        agent.act(np.zeros((3, 4 if task is CARTPOLE else 3), dtype=np.float32))
    _one_line_naming(err, spec)
    assert "observation 1" in str(err.value)


@pytest.mark.parametrize(("companion", "answer", "words"), [
    ("q_values", "[1.0]", "2 finite values"),
    ("q_values", "[1.0, float('inf')]", "2 finite values"),
    ("action_probabilities", "[0.7, 0.7]", "probabilities summing to 1"),
    ("action_probabilities", "[1.5, -0.5]", "probabilities summing to 1"),
])
def test_bad_companion_answers_are_one_line(tmp_path, companion, answer, words):
    path = write(tmp_path, RULE + f"act.{companion} = lambda obs: {answer}\n")
    spec = f"{path}:act"
    with pytest.raises(ValueError, match=words) as err:
        load_callable_agent(CARTPOLE, spec).label(OBS)
    _one_line_naming(err, spec)
    assert "observation 0" in str(err.value)


@pytest.mark.parametrize("answer", ["[0]", "3", "None", "[[0, 1], [1], 0]"])
def test_a_batched_agent_must_answer_one_row_per_observation(tmp_path, answer):
    path = write(tmp_path, f"def act(obs):\n    return {answer}\nact.batched = True\n")
    spec = f"{path}:act"
    with pytest.raises(ValueError, match="one row per observation") as err:
        load_callable_agent(CARTPOLE, spec).act(OBS)
    _one_line_naming(err, spec)


def test_the_agent_gets_copies_of_the_observations(tmp_path):
    path = write(tmp_path, "def act(obs):\n    obs[:] = 99\n    return 0\n")
    obs = OBS.copy()
    load_callable_agent(CARTPOLE, f"{path}:act").act(obs)
    assert np.array_equal(obs, OBS)


@pytest.mark.parametrize("weighted", [False, True])
def test_distillation_of_a_rule_imitates_it(tmp_path, weighted):
    source = RULE + ("act.q_values = lambda obs: [0.0, obs[2] + 0.1 * obs[3]]\n"
                     if weighted else "")
    agent = load_callable_agent(CARTPOLE, f"{write(tmp_path, source)}:act")
    config = DistillConfig.for_task(CARTPOLE, method="imitation-bt" if weighted else "dagger",
                                    n_iterations=2, labels_per_iteration=400,
                                    selection_episodes=2, max_leaf_nodes=6)
    record = distill(CARTPOLE, agent, config, seed=0, progress=False)
    assert record.expert == "callable" and record.expert_labels >= 800
    tree = CompiledTree(record.best_tree)
    visited = np.concatenate(rollout(CARTPOLE, lambda o: rule(o), range(5), collect=True).obs)
    agreement = (tree.predict(CARTPOLE.features(visited)) == rule(visited)).mean()
    assert agreement >= 0.9, agreement
    assert rollout(CARTPOLE, learner_policy(CARTPOLE, tree), range(5)).mean >= 150
    again = distill(CARTPOLE, agent, config, seed=0, progress=False)  # the same seed: the same
    assert [tree_signature(t) for t in again.trees] == [tree_signature(t) for t in record.trees]


def test_box_distillation_of_a_controller_imitates_it(tmp_path):
    path = write(tmp_path, "def act(obs):\n    return -2.0 * obs[1] - 0.5 * obs[2]\n")
    agent = load_callable_agent(PENDULUM, f"{path}:act")
    config = BoxDistillConfig.for_task(PENDULUM, method="dagger", n_iterations=2,
                                       labels_per_iteration=600, selection_episodes=1,
                                       max_leaf_nodes=12)
    record = distill_box(PENDULUM, agent, config, seed=0, progress=False)
    assert record.expert == "callable"
    visited = np.concatenate(rollout(PENDULUM, agent.act, range(3), collect=True).obs)
    target = agent.act(visited)[:, 0]
    error = np.abs(box_tree_policy(PENDULUM, record.best_tree)(visited)[:, 0] - target).mean()
    assert error < 0.4 * np.abs(target - target.mean()).mean(), error


def test_the_structure_search_takes_a_callable_agent_as_its_expert(tmp_path):
    from ibt.refine.structure import evolve
    from ibt.refine.structure_mutations import TreeMutator
    from ibt.tasks.settings import EvolveConfig

    source = RULE + "act.q_values = lambda obs: [0.0, obs[2] + 0.1 * obs[3]]\n"
    agent = load_callable_agent(CARTPOLE, f"{write(tmp_path, source)}:act")
    x = np.random.default_rng(0).normal(scale=0.1, size=(200, 4)).astype(np.float32)
    mutator = TreeMutator(CARTPOLE, EvolveConfig(max_leaves=4, leaf_rule="score"),
                          np.random.default_rng(0), agent)
    mutator.refresh(x)
    assert mutator.scores.shape == (200, 2)
    assert np.array_equal(mutator.labels, agent.act(CARTPOLE.observations(mutator.pool)))
    config = EvolveConfig(max_leaves=3, episodes=80, mu=2, lam=4, generation_episodes=4,
                          pool_episodes=2, selection_episodes=2, finalists=2, n_envs=8)
    stump = DistillConfig.for_task(CARTPOLE, method="bc", n_iterations=1,
                                   labels_per_iteration=200, selection_episodes=1,
                                   max_leaf_nodes=2)
    tree = distill(CARTPOLE, agent, stump, seed=0, progress=False).best_tree
    found = evolve([tree], CARTPOLE, config, seed=0, expert=agent, progress=False)
    assert found.best.n_leaves <= 3


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-3, 3)] * 3), min_size=1, max_size=8))
def test_batched_and_per_observation_agents_agree_inside_the_box(tmp_path_factory, rows):
    folder = tmp_path_factory.mktemp("law")
    path = write(folder, """
import numpy as np

def one(obs):
    return -2.0 * obs[1] - 0.5 * obs[2]

def many(obs):
    return -2.0 * obs[:, 1] - 0.5 * obs[:, 2]

many.batched = True
""")
    obs = np.array(rows, dtype=np.float32)
    one = load_callable_agent(PENDULUM, f"{path}:one").act(obs)
    many = load_callable_agent(PENDULUM, f"{path}:many").act(obs)
    assert np.array_equal(one, many)
    assert (np.abs(one) <= 2.0).all() and one.shape == (len(obs), 1)
