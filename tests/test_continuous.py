"""Continuous actions (issue 25): Box tasks, distillation into regression trees, named commands,
verified BTs with a command table, and their BehaviorTree.CPP export run in the stock engine."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.model import BehaviorTree, Commands
from ibt.distill.continuous import BoxDistillConfig, box_tree_policy, distill_box
from ibt.evaluate.rollouts import rollout
from ibt.experts.expert import load_expert
from ibt.export.btcpp import from_btcpp_xml, to_btcpp_xml
from ibt.synth.commands import (
    bt_actions,
    choose_commands,
    command_name,
    command_tree,
    leaf_table,
    with_commands,
)
from ibt.synth.imitation import verify
from ibt.synth.registry import SYNTHESISERS, get_synthesiser
from ibt.tasks.catalogue import get_task

PENDULUM = get_task("Pendulum-v1")
LANDER = get_task("LunarLanderContinuous-v3")


@pytest.fixture(scope="module")
def lander_tree():
    """A small BC tree of the committed PPO expert (one iteration: seconds)."""
    expert = load_expert(LANDER, "ppo")
    config = BoxDistillConfig.for_task(LANDER, method="bc", n_iterations=1,
                                       labels_per_iteration=1000, selection_episodes=2,
                                       max_leaf_nodes=8)
    return distill_box(LANDER, expert, config, seed=0, progress=False).best_tree


def test_box_tasks_say_so_and_check_actions():
    assert PENDULUM.continuous and LANDER.continuous and not get_task("CartPole-v1").continuous
    assert LANDER.action_names == ("main_engine", "side_engine") and LANDER.n_actions == 2
    ok = LANDER.check_action(np.array([[0.5, -1.0]]))
    assert ok.dtype == np.float32
    for bad in ([1.5, 0.0], [np.nan, 0.0], [0.0, -np.inf]):
        with pytest.raises(ValueError, match="outside"):
            LANDER.check_action(np.array([bad]))


def test_distillation_is_deterministic_and_acts_inside_the_box(lander_tree):
    expert = load_expert(LANDER, "ppo")
    config = BoxDistillConfig.for_task(LANDER, method="bc", n_iterations=1,
                                       labels_per_iteration=1000, selection_episodes=2,
                                       max_leaf_nodes=8)
    again = distill_box(LANDER, expert, config, seed=0, progress=False).best_tree
    x = LANDER.sample_features(500, np.random.default_rng(1))
    assert np.array_equal(again.predict(x), lander_tree.predict(x))
    assert lander_tree.get_n_leaves() <= 8
    _, values, visits = leaf_table(lander_tree)
    assert values.shape == (lander_tree.get_n_leaves(), 2) and (visits > 0).all()
    LANDER.check_action(values)  # leaf means of in-Box labels are in the Box


def test_distill_box_refuses_a_discrete_task():
    cartpole = get_task("CartPole-v1")
    with pytest.raises(ValueError, match="Box"):
        distill_box(cartpole, load_expert(cartpole, "ppo"), BoxDistillConfig(), progress=False)


@pytest.mark.parametrize("k", [1, 2, 3, 8])
def test_command_tree_decides_the_merged_command_of_each_leaf(lander_tree, k):
    ct = command_tree(lander_tree, LANDER, k)
    assert 1 <= ct.n_commands <= k
    x = LANDER.sample_features(2000, np.random.default_rng(k))
    leaf_of = {node: i for i, node in enumerate(leaf_table(lander_tree)[0])}
    ids = ct.tree.predict(x)
    # same splits: every state's command is its regression leaf's command
    leaves = lander_tree.apply(x)
    for leaf in np.unique(leaves):
        assert len(np.unique(ids[leaves == leaf])) == 1, leaf_of[leaf]
    assert np.allclose(ct.actions(x), ct.commands.array()[ids])
    LANDER.check_action(ct.commands.array())
    assert len(set(ct.task.action_names)) == ct.n_commands  # distinct readable names
    if k >= lander_tree.get_n_leaves():  # only rounding: within half a hundredth
        assert np.abs(ct.actions(x) - lander_tree.predict(x)).max() <= 0.005 + 1e-6


@pytest.mark.parametrize("method", sorted(SYNTHESISERS))
def test_every_synthesiser_gives_a_verified_bt_with_commands(lander_tree, method):
    ct = command_tree(lander_tree, LANDER, 4)
    bt = with_commands(get_synthesiser(method)(ct.tree, ct.task).bt, ct.commands)
    assert verify(bt, ct.tree, ct.task) > 0
    x = LANDER.sample_features(3000, np.random.default_rng(2))
    assert np.array_equal(bt_actions(bt, x), ct.actions(x))
    again = BehaviorTree.from_json(bt.to_json())
    assert again == bt and again.commands == ct.commands


def test_command_names_are_readable():
    assert command_name(LANDER, np.array([0.8, -0.3])) == "main_engine 0.8, side_engine -0.3"
    assert command_name(PENDULUM, np.array([-2.0])) == "torque -2 N m"
    assert command_name(PENDULUM, np.array([-0.0])) == "torque 0 N m"


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6), min_size=2, max_size=2), st.integers(1, 4))
def test_commands_round_trip_through_json(row, n):
    commands = Commands(("a", "b"), ("", "N"), tuple(tuple(row) for _ in range(n)))
    assert Commands.from_dict(json.loads(json.dumps(commands.to_dict())), n) == commands


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "0.5", True, None])
def test_a_bt_file_with_a_bad_command_value_is_refused(lander_tree, bad):
    ct = command_tree(lander_tree, LANDER, 2)
    bt = with_commands(get_synthesiser("imitation-bt")(ct.tree, ct.task).bt, ct.commands)
    doc = bt.to_dict()
    doc["commands"]["values"][0][1] = bad
    with pytest.raises(ValueError, match="finite number"):
        BehaviorTree.from_dict(json.loads(json.dumps(doc)))
    doc = bt.to_dict()
    doc["commands"]["values"].pop()
    with pytest.raises(ValueError, match="one command per action"):
        BehaviorTree.from_dict(doc)


def test_committed_discrete_bts_have_no_commands_key():
    from ibt.paths import DATA_DIR

    paths = sorted((DATA_DIR / "trees").glob("**/*.json"))[:20]
    assert paths
    for path in paths:
        bt = BehaviorTree.from_json(path.read_text())
        assert bt.commands is None and "commands" not in bt.to_dict()
        assert BehaviorTree.from_dict(bt.to_dict()) == bt


def test_engine_runs_commands_as_script_nodes_with_nothing_registered(lander_tree):
    """Decisions and command values equal on states in every region and on both sides of
    every threshold; engine rollouts return what the Python BT returns."""
    from ibt.export.agreement import agreement_states
    from ibt.export.engine import EnginePolicy, EngineTree

    ct = command_tree(lander_tree, LANDER, 4)
    bt = with_commands(get_synthesiser("decision-list")(ct.tree, ct.task).bt, ct.commands)
    xml = to_btcpp_xml(bt)
    assert "<Action" not in xml and "<Script code=\"command := " in xml
    assert from_btcpp_xml(xml, bt.feature_names, bt.action_names, commands=bt.commands) == bt
    engine = EngineTree(xml, LANDER.feature_names, bt.action_names, commands=bt.commands)
    states = agreement_states(bt, ct.task, n_random=2000)
    assert np.array_equal(engine.decide(states), bt.decide(states))
    assert np.array_equal(engine.act(states[:300]), bt_actions(bt, states[:300]))
    seeds = [900_000, 900_001]
    ours = rollout(LANDER, lambda obs: bt_actions(bt, LANDER.features(obs)), seeds)
    theirs = rollout(LANDER, EnginePolicy(LANDER, engine).act, seeds)
    assert np.array_equal(ours.returns, theirs.returns)


def test_engine_xml_with_a_changed_command_is_refused(lander_tree):
    ct = command_tree(lander_tree, LANDER, 2)
    bt = with_commands(get_synthesiser("imitation-bt")(ct.tree, ct.task).bt, ct.commands)
    xml = to_btcpp_xml(bt)
    value = repr(bt.commands.values[0][0])
    changed = xml.replace(f"main_engine := {value}", "main_engine := 0.123456", 1)
    assert changed != xml
    with pytest.raises(ValueError, match="command table"):
        from_btcpp_xml(changed, bt.feature_names, bt.action_names, commands=bt.commands)


def test_choose_commands_keeps_the_smallest_k_within_the_tolerance(lander_tree):
    seeds = [800_000 + i for i in range(4)]
    chosen, rows = choose_commands(lander_tree, LANDER, seeds, scale=478.8, tolerance=0.01)
    assert rows[-1]["k"] == len(rows) and chosen.n_commands <= rows[-1]["k"]
    last = rows[-1]
    assert last["loss"] <= 0.01 * 478.8 or last["k"] == lander_tree.get_n_leaves()
    assert all(r["loss"] > 0.01 * 478.8 for r in rows[:-1])
    reference = rollout(LANDER, box_tree_policy(LANDER, lander_tree), seeds).mean
    assert rows[0]["tree_return"] == reference


# ------------------------------------------------------------------------ command line
def _bt_file(tree, path, change=None):
    ct = command_tree(tree, LANDER, 3)
    doc = with_commands(get_synthesiser("decision-list")(ct.tree, ct.task).bt,
                        ct.commands).to_dict()
    if change is not None:
        change(doc)
    path.write_text(json.dumps(doc))
    return path


def _one_line_exit_2(argv, capsys, *words):
    from ibt.cli import main

    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and not captured.out, captured
    assert all(w in lines[0] for w in words), lines[0]


def test_cli_evaluates_and_exports_a_bt_with_commands(lander_tree, tmp_path, capsys):
    from ibt.cli import main

    path = _bt_file(lander_tree, tmp_path / "bt.json")
    assert main(["evaluate", str(path), "--task", LANDER.name, "--episodes", "2"]) == 0
    assert "mean return" in capsys.readouterr().out
    xml = tmp_path / "bt.xml"
    assert main(["export", str(path), "--format", "btcpp-xml", "-o", str(xml)]) == 0
    assert "<Script code=\"command := " in xml.read_text()


def test_cli_refuses_a_nan_command(lander_tree, tmp_path, capsys):
    def nan(doc):
        doc["commands"]["values"][0][0] = float("nan")

    path = _bt_file(lander_tree, tmp_path / "bt.json", nan)
    _one_line_exit_2(["export", str(path), "--format", "btcpp-xml", "-o",
                      str(tmp_path / "bt.xml")], capsys, "finite")
    assert not (tmp_path / "bt.xml").exists()


def test_cli_refuses_a_command_outside_the_box(lander_tree, tmp_path, capsys):
    def outside(doc):
        doc["commands"]["values"][0][1] = 3.0

    path = _bt_file(lander_tree, tmp_path / "bt.json", outside)
    _one_line_exit_2(["evaluate", str(path), "--task", LANDER.name, "--episodes", "1"], capsys,
                     "outside", "action space")


def test_cli_refuses_a_checkpoint_of_another_action_space(tmp_path, capsys):
    from ibt.experts.expert import expert_path

    cartpole = expert_path(get_task("CartPole-v1"), "ppo")
    _one_line_exit_2(["distill", PENDULUM.name, "ppo", "--checkpoint", str(cartpole), "-o",
                      str(tmp_path / "t.json")], capsys, "Discrete", "Box")
    assert not (tmp_path / "t.json").exists()


def test_cli_distils_synthesises_evaluates_and_exports_a_box_task(tmp_path, capsys):
    """The chain on Pendulum with a tiny budget: a command tree file, a verified BT with its
    command table, the same return from both, and XML of built-in nodes only."""
    from ibt.cli import main
    from ibt.distill.tree_file import load_tree_file

    tree, bt_file, xml = tmp_path / "t.json", tmp_path / "bt.json", tmp_path / "bt.xml"
    assert main(["distill", PENDULUM.name, "sac", "-o", str(tree), "--iterations", "2",
                 "--labels", "400", "--selection-episodes", "2", "--max-leaf-nodes", "4",
                 "--quiet"]) == 0
    doc = load_tree_file(tree)
    assert doc["tree"].get_n_leaves() <= 4 and Commands.from_dict(
        doc["commands"], len(doc["action_names"])).dimensions == ("torque",)
    assert main(["synthesize", str(tree), "-o", str(bt_file)]) == 0
    bt = BehaviorTree.from_json(bt_file.read_text())
    assert bt.commands is not None and bt.action_names == tuple(doc["action_names"])
    capsys.readouterr()
    assert main(["evaluate", str(tree), "--episodes", "3"]) == 0
    from_tree = capsys.readouterr().out
    assert main(["evaluate", str(bt_file), "--task", PENDULUM.name, "--episodes", "3"]) == 0
    assert capsys.readouterr().out == from_tree
    assert main(["export", str(bt_file), "--format", "btcpp-xml", "-o", str(xml)]) == 0
    assert "<Action" not in xml.read_text()
    capsys.readouterr()
    _one_line_exit_2(["refine", str(tree), "-o", str(tmp_path / "r.json"), "--max-leaves",
                      "2"], capsys, "command tree")
    # refinement by return of a command tree: same shape, same command count, a valid file
    assert main(["refine", str(tree), "-o", str(tmp_path / "r.json"), "--episodes", "200",
                 "--quiet"]) == 0
    refined = load_tree_file(tmp_path / "r.json")
    assert refined["tree"].get_n_leaves() <= doc["tree"].get_n_leaves()
    assert len(refined["commands"]["values"]) == len(doc["commands"]["values"])


def test_a_gymnasium_box_env_becomes_a_task_with_commands():
    from ibt.tasks.catalogue import task_from_env

    task = task_from_env("BipedalWalker-v3")
    assert task.continuous and task.action_names == ("u0", "u1", "u2", "u3")
    assert task.action_low == (-1.0,) * 4 and task.budget.max_leaf_nodes == 8
