"""A user's own gymnasium environment through the command line (``--env-module``).

A tiny environment lives in a module written to a temporary folder, as a user's would; a tiny
PPO expert is trained on it here; then ``distill -> synthesize -> evaluate -> export`` run
through ``python -m ibt``'s ``main`` with ``--env-module`` (and gymnasium's ``module:EnvId``).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from ibt.cli import main
from ibt.distill.tree_file import load_tree_file
from ibt.tasks.catalogue import TASKS
from ibt.tasks.settings import DEFAULT_MAX_LEAF_NODES

TINY = ["--iterations", "2", "--labels", "100", "--selection-episodes", "2", "--quiet"]

ENV_SOURCE = '''
"""A user's environment: walk right along a corridor to the goal (registers Corridor-v0)."""

import gymnasium as gym
import numpy as np


class Corridor(gym.Env):
    """Observation (position, speed) in [-1, 1]^2; actions 0 = push left, 1 = push right."""

    def __init__(self):
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.v = float(self.np_random.uniform(-0.5, 0.5)), 0.0
        return self._obs(), {}

    def step(self, action):
        self.v = float(np.clip(self.v + (0.05 if int(action) == 1 else -0.05), -0.2, 0.2))
        self.x = float(np.clip(self.x + self.v, -1.0, 1.0))
        done = self.x >= 1.0
        return self._obs(), 0.0 if done else -1.0, done, False, {}

    def _obs(self):
        return np.array([self.x, self.v / 0.2], dtype=np.float32)


gym.register(id="Corridor-v0", entry_point=f"{__name__}:Corridor", max_episode_steps=60)
gym.register(id="NamedCorridor-v0", entry_point=f"{__name__}:Corridor", max_episode_steps=60)
'''

# the optional part: a module that also registers an ibt task, for readable names
NAMED_SOURCE = '''
import ibt_user_corridor  # registers the environments
from ibt.tasks.catalogue import Task, register_task

register_task(Task(name="NamedCorridor-v0", gym_id="NamedCorridor-v0",
                   feature_names=("position", "speed"), action_names=("left", "right"),
                   low=(-1.0, -1.0), high=(1.0, 1.0), setup_module=__name__))
'''


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    """The user's folder: the environment modules on sys.path, and a tiny PPO checkpoint."""
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger

    folder = tmp_path_factory.mktemp("user")
    (folder / "ibt_user_corridor.py").write_text(ENV_SOURCE)
    (folder / "ibt_user_corridor_named.py").write_text(NAMED_SOURCE)
    sys.path.insert(0, str(folder))
    import ibt_user_corridor  # noqa: F401

    model = PPO("MlpPolicy", gym.make("Corridor-v0"), n_steps=64, batch_size=64, n_epochs=1,
                seed=0, device="cpu", policy_kwargs={"net_arch": [16]})
    model.set_logger(Logger(None, []))  # no empty /tmp/SB3-<date> folder
    model.learn(64)
    model.save(folder / "ppo.zip")
    yield folder
    sys.path.remove(str(folder))
    TASKS.pop("NamedCorridor-v0", None)


def _png_size(path: Path) -> tuple[int, int]:
    width, height = struct.unpack(">II", path.read_bytes()[16:24])
    return width, height


def test_own_environment_distils_synthesises_evaluates_and_exports(user, tmp_path, capsys):
    env = ["--env-module", "ibt_user_corridor"]
    tree, bt = tmp_path / "tree.json", tmp_path / "bt.json"
    assert main(["distill", "Corridor-v0", "ppo", "--checkpoint", str(user / "ppo.zip"),
                 "-o", str(tree), *TINY, *env]) == 0
    assert f"of at most {DEFAULT_MAX_LEAF_NODES}" in capsys.readouterr().out
    doc = load_tree_file(tree)
    assert doc["task"] == "Corridor-v0" and doc["env_modules"] == ["ibt_user_corridor"]
    assert doc["tree"].get_n_leaves() <= DEFAULT_MAX_LEAF_NODES  # a readable tree by default
    assert main(["synthesize", str(tree), "-o", str(bt), *env]) == 0
    assert json.loads(bt.read_text())["feature_names"] == ["x0", "x1"]
    capsys.readouterr()
    assert main(["evaluate", str(bt), "--task", "Corridor-v0", "--episodes", "3", *env]) == 0
    bt_line = capsys.readouterr().out.strip()
    assert main(["evaluate", str(tree), "--episodes", "3", *env]) == 0
    assert capsys.readouterr().out.strip() == bt_line  # the BT plays exactly as its tree
    assert bt_line.startswith("Corridor-v0: mean return")
    assert main(["export", str(bt), "--format", "png", "-o", str(tmp_path / "bt.png"), *env]) == 0
    width, height = _png_size(tmp_path / "bt.png")
    assert 0 < width < 4000 and 0 < height < 4000
    assert main(["export", str(bt), "--format", "btcpp-xml", "-o", str(tmp_path / "bt.xml")]) == 0


def test_a_registered_task_gives_readable_names(user, tmp_path):
    env = ["--env-module", "ibt_user_corridor_named"]
    tree, bt = tmp_path / "tree.json", tmp_path / "bt.json"
    assert main(["distill", "NamedCorridor-v0", "ppo", "--checkpoint", str(user / "ppo.zip"),
                 "-o", str(tree), *TINY, *env]) == 0
    assert main(["synthesize", str(tree), "-o", str(bt), *env]) == 0
    doc = json.loads(bt.read_text())
    assert doc["feature_names"] == ["position", "speed"]
    assert doc["action_names"] == ["left", "right"]


def test_gymnasiums_module_colon_id_form(user, tmp_path):
    tree = tmp_path / "tree.json"
    assert main(["distill", "ibt_user_corridor:Corridor-v0", "ppo", "--checkpoint",
                 str(user / "ppo.zip"), "-o", str(tree), *TINY]) == 0
    assert load_tree_file(tree)["env_modules"] == ["ibt_user_corridor"]


def test_a_fresh_process_is_told_the_missing_env_module_and_the_hint_works(user, tmp_path):
    # Expect: without --env-module, synthesize fails with a command that works
    tree = tmp_path / "tree.json"
    assert main(["distill", "Corridor-v0", "ppo", "--checkpoint", str(user / "ppo.zip"),
                 "-o", str(tree), *TINY, "--env-module", "ibt_user_corridor"]) == 0
    environ = {**os.environ, "PYTHONPATH": str(user)}
    command = [sys.executable, "-m", "ibt", "synthesize", str(tree), "-o",
               str(tmp_path / "bt.json")]
    failed = subprocess.run(command, capture_output=True, text=True, env=environ,
                            cwd=tmp_path, timeout=120)
    assert failed.returncode == 2 and len(failed.stderr.splitlines()) == 1
    hint = re.findall(r"`([^`]+)`", failed.stderr)[0]
    assert hint.startswith("python -m ibt synthesize") and "--env-module ibt_user_corridor" in hint
    assert not (tmp_path / "bt.json").exists()
    ran = subprocess.run([sys.executable, *shlex.split(hint)[1:]], capture_output=True,
                         text=True, env=environ, cwd=tmp_path, timeout=120)
    assert ran.returncode == 0, ran.stderr
    assert (tmp_path / "bt.json").exists()


def test_the_readmes_own_environment_commands_work(user, tmp_path, monkeypatch):
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    section = readme.split("### Distil your own agent", 1)[1]
    blocks = [b.split("```", 1)[0] for b in section.split("```bash")[1:]]
    block = next(b for b in blocks if " distill " in b)  # the single steps
    commands = [line.split("#")[0].strip() for line in block.strip().splitlines()]
    assert len(commands) >= 4 and all(c.startswith("python -m ibt ") for c in commands)
    monkeypatch.chdir(tmp_path)
    for command in commands:
        argv = [{"my_envs": "ibt_user_corridor", "MyEnv-v0": "Corridor-v0",
                 "my_envs:MyEnv-v0": "ibt_user_corridor:Corridor-v0",
                 "my_agent.zip": str(user / "ppo.zip")}.get(a, a)
                for a in shlex.split(command)[3:]]
        if argv[0] == "distill":
            argv += TINY
        if argv[0] == "evaluate":
            argv += ["--episodes", "2"]
        assert main(argv) == 0, command
    assert (tmp_path / "bt.png").exists()


@pytest.mark.slow
def test_a_trained_expert_of_the_users_environment_keeps_its_return_as_a_bt(user, tmp_path,
                                                                            capsys):
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger

    checkpoint = tmp_path / "ppo.zip"
    model = PPO("MlpPolicy", gym.make("Corridor-v0"), n_steps=256, batch_size=64, seed=0,
                device="cpu", policy_kwargs={"net_arch": [16]})
    model.set_logger(Logger(None, []))  # no empty /tmp/SB3-<date> folder
    model.learn(20_000)
    model.save(checkpoint)
    env = ["--env-module", "ibt_user_corridor"]
    tree, bt = tmp_path / "tree.json", tmp_path / "bt.json"
    assert main(["distill", "Corridor-v0", "ppo", "--checkpoint", str(checkpoint), "-o",
                 str(tree), "--iterations", "5", "--quiet", *env]) == 0
    assert main(["synthesize", str(tree), "-o", str(bt), *env]) == 0
    capsys.readouterr()
    returns = {}
    for policy in (["ppo", "--checkpoint", str(checkpoint)], [str(bt)]):
        assert main(["evaluate", *policy, "--task", "Corridor-v0", "--episodes", "20", *env]) == 0
        returns[policy[0]] = float(capsys.readouterr().out.split("mean return ")[1].split()[0])
    assert returns["ppo"] > -30  # the expert reaches the goal
    assert returns[str(bt)] >= returns["ppo"] - 2.0  # and so does its small BT
    assert json.loads(bt.read_text())["root"]  # a BT of at most 16 leaves' rules
