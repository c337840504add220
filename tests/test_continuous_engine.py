"""``run-btcpp`` on continuous tasks (issue 25): the stock BehaviorTree.CPP engine reads a BT's
command table from its ``Script`` nodes, and its rollouts return what the Python BT returns."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.tree import DecisionTreeRegressor

from ibt.engine.synthesis import command_bt
from ibt.export.btcpp import to_btcpp_xml
from ibt.export.engine import run_btcpp, xml_commands
from ibt.refine.commands import CommandArrays
from ibt.synth.commands import command_tree
from ibt.tasks.catalogue import get_task


def _bt(task_name: str, leaves: int, seed: int):
    """A verified BT with commands of a hand-made regression tree (no expert needed)."""
    task = get_task(task_name)
    rng = np.random.default_rng(seed)
    x = task.sample_features(3000, rng)
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    y = np.clip(np.tanh(x[:, -1:] * 3 + x[:, :1]) * high, low, high) * np.ones(task.n_actions)
    tree = DecisionTreeRegressor(max_leaf_nodes=leaves, random_state=0).fit(x, y)
    arrays = CommandArrays.from_command_tree(command_tree(tree, task, leaves))
    return task, command_bt(arrays, task, "imitation-bt")


@pytest.mark.parametrize("task_name", ["MountainCarContinuous-v0", "Pendulum-v1",
                                       "LunarLanderContinuous-v3"])
def test_engine_rollouts_equal_the_python_bt(tmp_path, task_name):
    task, bt = _bt(task_name, 6, 0)
    path = tmp_path / "bt.xml"
    path.write_text(to_btcpp_xml(bt))
    assert xml_commands(path.read_text(), task) == bt.commands
    run = run_btcpp(path, task, episodes=2)
    assert run.ok, run.summary()
    assert np.array_equal(run.comparison.engine.returns, run.comparison.python.returns)
    assert run.comparison.ticks > 0 and run.comparison.disagreements == 0


def test_engine_refuses_a_command_outside_the_box_and_a_nan(tmp_path):
    task, bt = _bt("MountainCarContinuous-v0", 4, 1)
    xml = to_btcpp_xml(bt)
    key = "force := "
    start = xml.index(key) + len(key)
    end = min(xml.index(c, start) for c in ('"', ";") if c in xml[start:])
    for bad, match in (("5.0", "outside"), ("nan", "finite")):
        path = tmp_path / f"{bad}.xml"
        path.write_text(xml[:start] + bad + xml[end:])
        with pytest.raises(ValueError, match=match):
            run_btcpp(path, task, episodes=1)


def _committed() -> list[tuple[str, object]]:
    """Every committed BT with commands (``data/trees/<task>/<expert>/*.json``) and its task."""
    from ibt.bt.json_io import load_json
    from ibt.paths import DATA_DIR

    found = []
    for path in sorted((DATA_DIR / "trees").glob("*/*/*.json")):
        task = path.parts[-3]
        if task in ("LunarLanderContinuous-v3", "Pendulum-v1", "MountainCarContinuous-v0"):
            found.append((task, load_json(path)))
    return found


def test_every_committed_continuous_bt_loads_in_the_stock_engine_and_agrees():
    """Nothing registered; decisions and command values equal on states inside every region
    and on both sides of every threshold; its committed XML is what the exporter writes."""
    from ibt.export.agreement import agreement_states
    from ibt.export.engine import EngineTree
    from ibt.paths import DATA_DIR
    from ibt.synth.commands import bt_actions

    committed = _committed()
    if not committed:
        pytest.skip("no continuous BT committed yet")
    for task_name, bt in committed:
        task = get_task(task_name)
        xml = to_btcpp_xml(bt)
        on_disk = sorted((DATA_DIR / "trees" / task_name).glob("*/*.xml"))
        assert any(p.read_text() == xml for p in on_disk), task_name
        engine = EngineTree(xml, task.feature_names, bt.action_names, commands=bt.commands)
        assert engine.command_keys is not None
        states = agreement_states(bt, task, n_random=2000)
        assert np.array_equal(engine.decide(states), bt.decide(states))
        assert np.array_equal(engine.act(states[:500]), bt_actions(bt, states[:500]))
