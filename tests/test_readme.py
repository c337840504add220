"""The README as a newcomer reads it: its code blocks run, its examples match committed files.

Every ``bash`` and ``python`` block of the README is classified in :data:`BLOCKS` by its first
line: ``run`` (run here, in process, in a scratch folder, ``ibt`` commands with the small
budget flags of :data:`FAST` appended: as written, distillation and refinement take minutes),
``elsewhere`` (another test runs it) or ``skip`` with the reason. A new block fails
:func:`test_every_block_is_classified` until it is classified.
"""

from __future__ import annotations

import re
import shlex
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"

#: first line of a block -> (how, reason)
BLOCKS = {
    "make figures": ("skip", "make figures/make test: minutes each; the lead runs them"),
    "python -m ibt train CartPole-v1": ("run", "the command-line chain on CartPole"),
    "python -m ibt pipeline MyEnv-v0": ("run", "the one command, on the README's my_envs"),
    "python -m ibt distill MyEnv-v0": ("run", "the single steps on the README's my_envs"),
    "# my_envs.py": ("run", "the user's module (with a MyEnv class added)"),
}
#: budget flags appended to a command so that the block runs in seconds here
FAST = {"distill": ["--iterations", "2", "--labels", "100", "--selection-episodes", "2"],
        "refine": ["--episodes", "200"], "evaluate": ["--episodes", "5"],
        "run-btcpp": ["--episodes", "2"], "pipeline": ["--budget", "smoke", "--leaves", "4"]}


def blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", README.read_text(), flags=re.M | re.S)


def _first_line(block: str) -> str:
    return block.strip().splitlines()[0]


def _kind(block: str) -> tuple[str, str]:
    first = _first_line(block)
    return next(v for k, v in BLOCKS.items() if first.startswith(k))


def test_every_block_is_classified():
    for block in blocks("bash") + blocks("python"):
        first = _first_line(block)
        assert any(first.startswith(k) for k in BLOCKS), f"classify README block {first!r}"


def _commands(block: str) -> list[list[str]]:
    """The block's ``python -m ibt`` commands as argument lists, comments dropped."""
    out = []
    for line in block.splitlines():
        words = shlex.split(line, comments=True)
        if words[:3] == ["python", "-m", "ibt"]:
            out.append(words[3:] + FAST.get(words[3], []))
        elif words:
            raise AssertionError(f"not an ibt command: {line!r}; classify its block")
    return out


def _run_block(block: str) -> None:
    from ibt.cli import main

    for argv in _commands(block):
        assert main(argv) == 0, f"python -m ibt {shlex.join(argv)} failed"


def _block(first: str) -> str:
    return next(b for b in blocks("bash") + blocks("python") if _first_line(b).startswith(first))


pytestmark = pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")


def test_the_command_line_chain_runs(tmp_path, monkeypatch, capsys):
    from ibt.cli import main

    monkeypatch.chdir(tmp_path)
    train, *rest = _commands(_block("python -m ibt train CartPole-v1"))
    assert train[0] == "train" and main(train) == 0
    said = capsys.readouterr().out
    assert "skipped 1 expert(s) already recorded" in said  # the committed one is kept
    assert max(len(line) for line in said.splitlines()) <= 120  # its table fits a terminal
    for argv in rest:
        assert main(argv) == 0, f"python -m ibt {shlex.join(argv)} failed"
    assert {"bt.json", "bt.xml"} <= {p.name for p in tmp_path.iterdir()}


MY_ENV = '''
import numpy as np


class MyEnv(gym.Env):
    """distance to a wall and speed; brake or go (the README's names)."""

    def __init__(self):
        self.observation_space = gym.spaces.Box(np.array([0.0, -5.0], np.float32),
                                                np.array([100.0, 5.0], np.float32))
        self.action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state = np.array([self.np_random.uniform(20, 100), 0.0])
        return self.state.astype(np.float32), {}

    def step(self, action):
        distance, speed = self.state
        speed = float(np.clip(speed + (1.0 if action == 1 else -1.0), 0.0, 5.0))
        distance = max(0.0, distance - speed)
        self.state = np.array([distance, speed])
        crashed = distance == 0.0
        return self.state.astype(np.float32), -10.0 if crashed else speed / 5, crashed, False, {}


class MyArm(gym.Env):
    """angle and angular velocity; a torque in [-2, 2] N m (the README's continuous task)."""

    def __init__(self):
        self.observation_space = gym.spaces.Box(np.array([-3.2, -8.0], np.float32),
                                                np.array([3.2, 8.0], np.float32))
        self.action_space = gym.spaces.Box(-2.0, 2.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state = self.np_random.uniform([-1.0, -1.0], [1.0, 1.0])
        return self.state.astype(np.float32), {}

    def step(self, action):
        angle, velocity = self.state
        velocity = float(np.clip(velocity + 0.1 * float(action[0]), -8.0, 8.0))
        self.state = np.array([np.clip(angle + 0.05 * velocity, -3.2, 3.2), velocity])
        return self.state.astype(np.float32), -abs(self.state[0]), False, False, {}
'''


@pytest.fixture
def my_envs(tmp_path, monkeypatch):
    """The README's ``my_envs.py`` (with a ``MyEnv`` class) and a small agent, in a scratch
    folder on ``sys.path``."""
    import gymnasium as gym

    from ibt.experts.expert import train_expert
    from ibt.tasks.catalogue import TASKS, resolve_task
    from ibt.tasks.settings import hp

    source = _block("# my_envs.py")
    header, _, rest = source.partition("gym.register(")
    (tmp_path / "my_envs.py").write_text(header + MY_ENV + "\n\ngym.register(" + rest)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    import my_envs  # noqa: F401

    task = replace(resolve_task("MyEnv-v0"),
                   experts=(("ppo", hp(1024, 1, n_steps=256, batch_size=64)),))
    train_expert(task, "ppo", tmp_path / "my_agent.zip", progress=False)
    yield tmp_path
    for name in ("MyEnv-v0", "MyArm-v0"):
        TASKS.pop(name, None)
        gym.registry.pop(name, None)
    sys.modules.pop("my_envs", None)


def test_the_distil_your_own_agent_blocks_run(my_envs):
    _run_block(_block("python -m ibt pipeline MyEnv-v0"))
    assert {"bt.json", "bt.xml", "bt.png", "front.png", "report.md"} <= {
        p.name for p in (my_envs / "my_bt").iterdir()}
    _run_block(_block("python -m ibt distill MyEnv-v0"))
    assert (my_envs / "bt.png").exists()


def test_the_readmes_continuous_task_is_registered_with_its_fields(my_envs):
    # Expect: the README's continuous example is a continuous task whose fields the docs name,
    # checked against its environment's action Box when registered
    from ibt.tasks.catalogue import resolve_task

    arm = resolve_task("MyArm-v0")
    assert arm.continuous and arm.action_names == ("torque",)
    assert (arm.action_low, arm.action_high, arm.action_units) == ((-2.0,), (2.0,), ("N m",))
    fields = (ROOT / "docs" / "own-agent.md").read_text()
    for name in ("action_low", "action_high", "action_units", "feature_names", "low", "high"):
        assert f"`{name}`" in fields, name


def test_the_btcpp_example_is_a_committed_trees_condition():
    # Expect: the XML element the README shows is one the exporter writes for a committed tree
    from ibt.bt.json_io import load_json
    from ibt.export.btcpp import to_btcpp_xml

    shown = re.findall(r"`(<ScriptCondition [^`]*/>)`", README.read_text().replace("\n", " "))
    assert shown, "the README shows no ScriptCondition"
    xml = " ".join(to_btcpp_xml(load_json(p)) for p in sorted((ROOT / "data" / "trees").rglob(
        "imitation-bt.json")))
    for element in shown:
        assert re.sub(r"\s+", " ", element) in xml, f"{element} is in no committed tree"


def test_highway_minutes_are_the_csvs():
    table = pd.read_csv(ROOT / "data" / "results" / "distillation.csv")
    minutes = table.loc[table.task == "highway-fast-v0", "wall_seconds"] / 60
    said = f"10 iterations took {minutes.min():.1f} to {minutes.max():.1f} minutes"
    assert said in " ".join((ROOT / "paper" / "method.md").read_text().split())


def test_the_readme_is_one_screen_first():
    # Expect: short, the lead GIF and the two commands before the headline table
    text = README.read_text()
    assert len(text.splitlines()) <= 270  # the controllers block joined the headline
    first = text.index
    assert first("figures/anim/") < first("make figures") < first("make test") < first(
        HEADLINE_BEGIN_MARK)


HEADLINE_BEGIN_MARK = "<!-- headline:begin"


def test_the_headline_table_is_the_committed_csv():
    # Expect: the README's headline block is exactly what headline.csv renders to, and every
    # file a row names is committed
    from ibt.report.markdown import HEADLINE_BEGIN, HEADLINE_END, front_page_block

    headline = pd.read_csv(ROOT / "data" / "results" / "headline.csv")
    text = README.read_text()
    shown = HEADLINE_BEGIN + text.split(HEADLINE_BEGIN, 1)[1].split(HEADLINE_END, 1)[0] + \
        HEADLINE_END
    assert shown == front_page_block(headline)
    for column in ("json_file", "xml_file", "png_file", "svg_file", "gif_file"):
        assert all((ROOT / path).is_file() for path in headline[column]), column


#: what Groot2's free edition monitors: a BT of at most this many nodes
GROOT2_FREE_NODES = 20


def test_the_groot2_sentence_is_the_headline_csv():
    # Expect: the README names exactly the headline BTs that Groot2's free monitor shows, with
    # node counts as the committed bt.xml files hold them, and the others' range
    import xml.etree.ElementTree as ET

    headline = pd.read_csv(ROOT / "data" / "results" / "headline.csv").drop_duplicates(
        "json_file")
    for row in headline.itertuples():
        trees = ET.parse(ROOT / row.xml_file).getroot().findall("BehaviorTree")
        assert sum(len(list(tree.iter())) - 1 for tree in trees) == row.bt_nodes, row.xml_file
    fits = headline[headline.bt_nodes <= GROOT2_FREE_NODES]
    others = headline[headline.bt_nodes > GROOT2_FREE_NODES]
    named = " and ".join(f"{r.task} ({r.expert.upper()}, {r.bt_nodes} nodes)"
                         for r in fits.itertuples())
    said = (f"Groot2's free edition monitors a running BT of up to {GROOT2_FREE_NODES} nodes: of "
            f"the headline BTs, " + (f"all {len(fits)} fit." if others.empty else
                                     f"{named} fit; the others have {others.bt_nodes.min()} to "
                                     f"{others.bt_nodes.max()} nodes."))
    assert said in " ".join(README.read_text().split())


def test_the_package_list_names_every_sub_package():
    # Expect: the "What is where" row of ibt/ names each sub-package (a folder with __init__.py)
    row = next(line for line in README.read_text().splitlines() if line.startswith("| `ibt/`"))
    named = set(re.findall(r"`([a-z_]+)`", row))
    packages = {p.parent.name for p in (ROOT / "ibt").glob("*/__init__.py")}
    assert packages <= named, sorted(packages - named)


def test_no_public_text_cites_the_tracker():
    pattern = re.compile(r"issues? #?[0-9]+|the issue's", re.I)
    pages = [README, *(ROOT / "docs").rglob("*.md"), *(ROOT / "paper").rglob("*.md")]
    cited = [f"{p.name}: {m.group(0)}" for p in pages for m in pattern.finditer(p.read_text())]
    assert cited == []
