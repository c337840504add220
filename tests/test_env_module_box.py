"""A user's own gymnasium environment with a ``Box`` action space, from the command line with
``--env-module`` and a SAC checkpoint (issue 25): distil, synthesise, evaluate, export, with a
readable BT by default; bad input gets exit 2 and one line.

A tiny SAC agent is trained here for a few hundred steps: the test checks the path, not the
agent's quality.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ibt.cli import main
from ibt.distill.tree_file import load_tree_file
from ibt.tasks.settings import BOX_MAX_LEAF_NODES

TINY = ["--iterations", "2", "--labels", "200", "--selection-episodes", "2", "--quiet"]

ENV_SOURCE = '''
"""A user's environment: hold a cart at the origin with a force in [-1, 1] (Thruster-v0)."""

import gymnasium as gym
import numpy as np


class Thruster(gym.Env):
    """Observation (position, velocity) in [-1, 1]^2; action: a force in [-1, 1]."""

    def __init__(self):
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.v = float(self.np_random.uniform(-0.8, 0.8)), 0.0
        return self._obs(), {}

    def step(self, action):
        force = float(np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -1, 1))
        self.v = float(np.clip(self.v + 0.02 * force, -0.2, 0.2))
        self.x = float(np.clip(self.x + self.v, -1.0, 1.0))
        return self._obs(), -abs(self.x), False, False, {}

    def _obs(self):
        return np.array([self.x, self.v / 0.2], dtype=np.float32)


gym.register(id="Thruster-v0", entry_point=f"{__name__}:Thruster", max_episode_steps=50)
'''


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    """The user's folder: the environment module on sys.path, and a tiny SAC checkpoint."""
    import gymnasium as gym
    from stable_baselines3 import SAC
    from stable_baselines3.common.logger import Logger

    folder = tmp_path_factory.mktemp("user_box")
    (folder / "ibt_user_thruster.py").write_text(ENV_SOURCE)
    sys.path.insert(0, str(folder))
    import ibt_user_thruster  # noqa: F401

    model = SAC("MlpPolicy", gym.make("Thruster-v0"), learning_starts=50, batch_size=32,
                seed=0, device="cpu", policy_kwargs={"net_arch": [16]})
    model.set_logger(Logger(None, []))  # no empty /tmp/SB3-<date> folder
    model.learn(300)
    model.save(folder / "sac.zip")
    yield folder
    sys.path.remove(str(folder))


def _fails_with_one_line(argv: list[str], capsys) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.slow
def test_own_box_environment_distils_synthesises_evaluates_and_exports(user, tmp_path, capsys):
    env = ["--env-module", "ibt_user_thruster"]
    tree, bt = tmp_path / "tree.json", tmp_path / "bt.json"
    assert main(["distill", "Thruster-v0", "sac", "--checkpoint", str(user / "sac.zip"),
                 "-o", str(tree), *TINY, *env]) == 0
    out = capsys.readouterr().out
    assert f"of at most {BOX_MAX_LEAF_NODES}" in out and "commands" in out
    doc = load_tree_file(tree)
    assert doc["task"] == "Thruster-v0" and doc["env_modules"] == ["ibt_user_thruster"]
    assert doc["tree"].get_n_leaves() <= BOX_MAX_LEAF_NODES  # a readable BT by default
    refined = tmp_path / "refined.json"
    assert main(["refine", str(tree), "-o", str(refined), "--episodes", "120", "--quiet",
                 *env]) == 0
    assert "refinement episodes" in capsys.readouterr().out
    assert load_tree_file(refined)["tree"].get_n_leaves() <= doc["tree"].get_n_leaves()
    assert main(["synthesize", str(refined), "-o", str(bt), *env]) == 0
    tree = refined  # the refined command tree is evaluated beside its BT below
    written = json.loads(bt.read_text())
    assert len(written["commands"]["dimensions"]) == 1  # the one force dimension
    capsys.readouterr()
    assert main(["evaluate", str(bt), "--task", "Thruster-v0", "--episodes", "3", *env]) == 0
    bt_line = capsys.readouterr().out.strip()
    assert main(["evaluate", str(tree), "--episodes", "3", *env]) == 0
    assert capsys.readouterr().out.strip() == bt_line  # the BT plays exactly as its tree
    assert main(["export", str(bt), "--format", "png", "-o", str(tmp_path / "bt.png"),
                 *env]) == 0
    assert main(["export", str(bt), "--format", "btcpp-xml", "-o", str(tmp_path / "bt.xml"),
                 *env]) == 0
    assert main(["run-btcpp", str(tmp_path / "bt.xml"), "--task", "Thruster-v0",
                 "--episodes", "2", *env]) == 0

    # bad input: exit 2 and one line
    nan = dict(written, commands=dict(written["commands"],
                                      values=[[float("nan")]] * len(written["action_names"])))
    (tmp_path / "nan.json").write_text(json.dumps(nan))  # json writes NaN as NaN
    err = _fails_with_one_line(["evaluate", str(tmp_path / "nan.json"), "--task", "Thruster-v0",
                                "--episodes", "1", *env], capsys)
    assert "finite" in err
    outside = dict(written, commands=dict(written["commands"],
                                          values=[[3.0]] * len(written["action_names"])))
    (tmp_path / "outside.json").write_text(json.dumps(outside))
    err = _fails_with_one_line(["evaluate", str(tmp_path / "outside.json"), "--task",
                                "Thruster-v0", "--episodes", "1", *env], capsys)
    assert "outside" in err
    other = Path(__file__).parents[1] / "data" / "experts" / "LunarLanderContinuous-v3"
    checkpoint = next(other.rglob("*.zip"))
    _fails_with_one_line(["distill", "Thruster-v0", "ppo", "--checkpoint", str(checkpoint),
                          "-o", str(tmp_path / "other.json"), *TINY, *env], capsys)
    assert not (tmp_path / "other.json").exists()


def test_the_box_leaf_limit_is_printed_in_help():
    ran = subprocess.run([sys.executable, "-m", "ibt", "distill", "--help"],
                         capture_output=True, text=True, timeout=60)
    assert f"{BOX_MAX_LEAF_NODES} for other tasks with continuous actions" in " ".join(
        ran.stdout.split())
