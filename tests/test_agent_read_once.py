"""The agent is read once: the bytes digested are the bytes every process acts with. A
callable's ``.py`` file or an SB3 checkpoint replaced after the agent was read (a training job
saving to the same path) changes nothing a worker process loads, so no result can be filed
under the digest of the agent it replaced."""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from ibt.engine import agent as agent_module
from ibt.paths import DATA_DIR
from ibt.tasks.catalogue import get_task

TASK = get_task("CartPole-v1")
OBS = np.zeros((3, 4))


def _as_a_worker_gets_it(agent: agent_module.Agent) -> agent_module.Agent:
    """The agent as a worker process receives it (pickled), with nothing loaded there yet."""
    from ibt.experts import callable_agent, expert

    agent_module._load.cache_clear()
    agent_module._DATA.clear()
    callable_agent._load_file.cache_clear()
    expert._load_cached.cache_clear()
    return pickle.loads(pickle.dumps(agent))


def test_a_callable_file_replaced_mid_run_is_not_what_the_workers_run(tmp_path):
    path = tmp_path / "pilot.py"
    path.write_text("def act(obs):\n    return 0\n")
    agent = agent_module.callable_agent(TASK, f"{path}:act")
    path.write_text("def act(obs):\n    return 1\n")  # replaced while the run goes on
    worker = _as_a_worker_gets_it(agent)
    assert worker.digest == agent.digest
    assert worker.load().act(OBS).tolist() == [0, 0, 0]  # the agent digested, not the new one
    fresh = agent_module.callable_agent(TASK, f"{path}:act")
    assert fresh.digest != agent.digest and fresh.load().act(OBS).tolist() == [1, 1, 1]


def test_a_callable_module_changed_mid_run_is_refused(tmp_path, monkeypatch):
    (tmp_path / "named_pilot.py").write_text("def act(obs):\n    return 0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    agent = agent_module.callable_agent(TASK, "named_pilot:act")
    (tmp_path / "named_pilot.py").write_text("def act(obs):\n    return 1  # changed\n")
    with pytest.raises(ValueError, match="changed while the run went on"):
        _as_a_worker_gets_it(agent).load()


def test_a_checkpoint_replaced_mid_run_is_not_what_the_workers_load(tmp_path):
    path = tmp_path / "ppo.zip"
    shutil.copy(DATA_DIR / "experts" / "CartPole-v1" / "ppo.zip", path)
    agent = agent_module.sb3_agent(TASK, "ppo", path)
    before = agent.load().act(OBS)
    shutil.copy(DATA_DIR / "experts" / "CartPole-v1" / "dqn.zip", path)  # another agent now
    worker = _as_a_worker_gets_it(agent)
    assert worker.load().act(OBS).tolist() == before.tolist()
    assert worker.load().algo == "ppo"
    path.write_bytes(b"half a checkpoint")  # or one being written: still the agent digested
    assert _as_a_worker_gets_it(agent).load().act(OBS).tolist() == before.tolist()


def test_a_bad_checkpoint_is_named_by_the_users_path_not_the_private_copy(tmp_path):
    path = tmp_path / "mine.zip"
    path.write_bytes(b"not a zip at all")
    with pytest.raises(ValueError) as err:
        agent_module.sb3_agent(TASK, "ppo", path)
    assert str(path) in str(err.value) and "ibt-agent-" not in str(err.value)
    assert Path(path).read_bytes() == b"not a zip at all"
