"""Controller trees: linear commands and tests of up to four features, as BTs that steer.

Laws: a BT of a controller tree sends exactly the tree's command (in ``ibt`` and in stock
BehaviorTree.CPP); sums are added left to right in double everywhere; a document round-trips.
The forms' own laws (oblique forms, the left-to-right sum, script sums) are in
tests/test_linear_law.py; the BT's construction on hand-made trees in
tests/test_controller_bt_law.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.linear import linear_form
from ibt.bt.model import Action, BehaviorTree, Commands, Condition, Selector, Sequence
from ibt.distill.controller import (
    ControllerArrays,
    fit_model_tree,
    grow_best_first,
    sparse_fit,
    widen,
)
from ibt.synth.controller import check_states, controller_bt
from ibt.tasks.catalogue import get_task


def _controller(rng: np.random.Generator, n_features: int = 3, n_dims: int = 2,
                oblique: bool = True) -> ControllerArrays:
    """A depth-2 controller tree: root split, a split on the left, three leaves."""
    n = 5
    left, right = np.array([1, 3, -1, -1, -1]), np.array([2, 4, -1, -1, -1])
    split = np.zeros((n, n_features))
    split[0, 0] = 1.0
    if oblique:
        split[1, :3] = rng.normal(size=3).round(2) + 0.05
    else:
        split[1, 1] = 1.0
    threshold = np.array([rng.normal(), rng.normal(), 0, 0, 0])
    bias = np.zeros((n, n_dims))
    weights = np.zeros((n, n_dims, n_features))
    for leaf in (2, 3, 4):
        bias[leaf] = rng.normal(size=n_dims)
        for d in range(n_dims):
            features = rng.choice(n_features, size=min(n_features, 2), replace=False)
            weights[leaf, d, features] = rng.normal(size=len(features)) * 3
    return ControllerArrays(left, right, split, threshold, bias, weights)


# ------------------------------------------------------------------------ linear commands
def _linear_bt() -> BehaviorTree:
    steer = (((1, 10.0), (3, -10.0)), ((0, 0.5), (2, 1.0), (3, -1.0)))
    commands = Commands(("main", "side"), ("", ""), ((-1.0, 0.0), (0.5, 0.0)),
                        (steer, ((), ())))
    root = Selector((Sequence((Condition.relational(linear_form([(0, 0.5), (2, 1.0),
                                                                  (3, -1.0)]), ">", 0.05),
                               Action(0))), Action(1)))
    return BehaviorTree(root, ("x", "y", "vx", "vy"), ("steer", "idle"), commands=commands)


def test_a_linear_command_evaluates_its_terms_and_round_trips_as_format_2():
    bt = _linear_bt()
    x = widen(np.array([[0.2, 0.7, 0.3, 0.1], [0.0, 0.0, 0.0, 1.0]]))
    ids = bt.decide(x)
    sent = bt.commands.evaluate(ids, x)
    # Expect: row 0 passes the test (0.1 + 0.3 - 0.1 > 0.05) and sends -1 + 10 y - 10 vy
    assert ids.tolist() == [0, 1]
    assert sent[0, 0] == (-1.0 + 10.0 * x[0, 1]) + -10.0 * x[0, 3]
    assert sent[0, 1] == ((0.0 + 0.5 * x[0, 0]) + 1.0 * x[0, 2]) + -1.0 * x[0, 3]
    assert sent[1].tolist() == [0.5, 0.0]
    doc = bt.to_dict()
    assert doc["format"] == "ibt-behavior-tree/2"
    assert BehaviorTree.from_json(bt.to_json()) == bt
    assert bt.commands.text(0, bt.feature_names) == ["main := -1 + 10 * y - 10 * vy",
                                                     "side := 0.5 * x + vx - vy"]


def test_older_documents_stay_format_1_and_a_format_1_file_cannot_hold_linear_commands():
    plain = BehaviorTree(Selector((Action(0),)), ("x",), ("a",),
                         commands=Commands(("u",), ("",), ((0.5,),)))
    assert plain.to_dict()["format"] == "ibt-behavior-tree/1"
    assert "terms" not in plain.to_dict()["commands"]
    doc = _linear_bt().to_dict()
    doc["format"] = "ibt-behavior-tree/1"
    doc["tick_rule"] = plain.to_dict()["tick_rule"]
    with pytest.raises(ValueError, match="ibt-behavior-tree/2"):
        BehaviorTree.from_dict(doc)


@pytest.mark.parametrize("terms, problem", [
    ([[[[9, 1.0]], []], [[], []]], "reads feature 9"),
    ([[[[0, 1.0], [0, 2.0]], []], [[], []]], "each feature once"),
    ([[[[0, "a"]], []], [[], []]], "must be a number"),
    ([[[[0, 1.0]]], [[], []]], "one list of terms per dimension"),
    ([[[[0]], []], [[], []]], "pairs"),
])
def test_a_bad_terms_table_is_refused_naming_the_problem(terms, problem):
    doc = _linear_bt().to_dict()
    doc["commands"]["terms"] = terms
    doc["root"] = {"type": "selector", "children": [{"type": "action", "action": 1}]}
    with pytest.raises(ValueError, match=problem):
        BehaviorTree.from_dict(doc)


# ---------------------------------------------------------------------------- the learner
def test_sparse_fit_recovers_a_linear_law_on_at_most_max_terms_features():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 6))
    y = -1.0 + 10.0 * x[:, 1] - 10.0 * x[:, 3]
    bias, weights = sparse_fit(x, y, max_terms=4)
    # Expect: the two features of the law, their weights, nothing else
    assert math.isclose(bias, -1.0, abs_tol=1e-9)
    assert np.flatnonzero(weights).tolist() == [1, 3]
    assert np.allclose(weights[[1, 3]], [10.0, -10.0])


def test_a_model_tree_finds_the_switch_of_a_piecewise_linear_controller():
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, size=(3000, 4)).astype(np.float32)
    y = np.where(x[:, 0] <= 0.25, 1.0 + 2.0 * x[:, 1], -0.5 - 3.0 * x[:, 2])[:, None]
    tree = fit_model_tree(x, y, max_leaves=2)
    assert tree.n_leaves == 2 and tree.split[0].tolist() == [1.0, 0.0, 0.0, 0.0]
    assert abs(tree.threshold[0] - 0.25) < 0.05
    error = np.abs(tree.decide(x) - y)[:, 0]
    assert np.mean(error < 1e-4) > 0.99 and error.mean() < 1e-2
    assert tree.size()["command_terms"] == 2


# -------------------------------------------------------------- the BT decides as the tree
@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_a_controller_bt_sends_exactly_the_trees_command(seed, oblique):
    rng = np.random.default_rng(seed)
    tree = _controller(rng, oblique=oblique)
    task = get_task("LunarLanderContinuous-v3")
    tree = ControllerArrays(tree.left, tree.right,
                            np.pad(tree.split, ((0, 0), (0, task.n_features - 3))),
                            tree.threshold, tree.bias,
                            np.pad(tree.weights, ((0, 0), (0, 0), (0, task.n_features - 3))))
    states = check_states(tree, task, rng.normal(size=(200, task.n_features)), seed=seed,
                          n_random=300)
    built = controller_bt(tree, task, states)
    x = widen(states)
    # Expect: every state gets bit for bit the tree's command; one rule per leaf
    assert np.array_equal(built.bt.commands.evaluate(built.bt.decide(x), x), tree.decide(x))
    assert built.rules == tree.n_leaves and built.bt.node_count <= 4 * tree.n_leaves - 3
    assert BehaviorTree.from_json(built.bt.to_json()) == built.bt


def test_stock_behaviortree_cpp_computes_the_same_commands_bit_for_bit():
    from ibt.export.btcpp import from_btcpp_xml, to_btcpp_xml
    from ibt.export.engine import EngineTree

    rng = np.random.default_rng(7)
    task = get_task("Pendulum-v1")
    tree = _controller(rng, n_features=3, n_dims=1)
    states = check_states(tree, task, rng.normal(size=(300, 3)), n_random=500)
    bt = controller_bt(tree, task, states).bt
    xml = to_btcpp_xml(bt)
    assert "ScriptCondition" in xml and "torque := " in xml
    # Expect: the XML reads back as the same BT, and the engine writes the same doubles
    assert from_btcpp_xml(xml, bt.feature_names, bt.action_names, commands=bt.commands) == bt
    engine = EngineTree(xml, bt.feature_names, bt.action_names, commands=bt.commands)
    x = widen(states)
    ours = bt.commands.evaluate(bt.decide(x), x)
    disagreements = 0
    for row, want in zip(states, ours, strict=True):
        engine.tick(row)
        got = [engine.blackboard.get_double(k) for k in engine.command_keys[1:]]
        disagreements += got != want.tolist()
    assert disagreements == 0


def test_a_bt_that_would_send_another_command_is_not_written():
    rng = np.random.default_rng(3)
    task = get_task("Pendulum-v1")
    tree = _controller(rng, n_features=3, n_dims=1, oblique=False)
    states = check_states(tree, task, rng.normal(size=(50, 3)))
    built = controller_bt(tree, task, states)
    broken = ControllerArrays(tree.left, tree.right, tree.split, tree.threshold,
                              tree.bias + np.where(tree.left[:, None] == -1, 1e-9, 0.0),
                              tree.weights)
    with pytest.raises(ValueError, match="sends another command"):
        from ibt.synth import controller as synth_controller

        original = synth_controller.leaf_commands

        def stale(_tree, task):  # the BT of the old tree checked against the new one
            return original(tree, task)

        synth_controller.leaf_commands = stale
        try:
            controller_bt(broken, task, states)
        finally:
            synth_controller.leaf_commands = original
    assert built.disagreements == 0


# ------------------------------------------------------------------ reference controllers
def test_dsp_pendulum_formula_reads_as_published():
    from ibt.runs.reference_controllers import DSP_PENDULUM, prefix_formula

    fn, reads, constants = prefix_formula(DSP_PENDULUM[0])
    rng = np.random.default_rng(0)
    theta, thdot = rng.uniform(-1, 1, 50), rng.uniform(-8, 8, 50)
    obs = np.column_stack([np.cos(theta), np.sin(theta), thdot])
    expected = -2 * np.sin(theta) + (-8 * np.sin(theta) - 2 * thdot) / np.cos(theta)
    assert np.allclose(fn(obs), expected) and (reads, constants) == (4, 3)
    for bad, problem in (("add,x1", "ends early"), ("x1,x2", "after its end"),
                         ("add,x1,nan", "constant")):
        with pytest.raises(ValueError, match=problem):
            prefix_formula(bad)


def test_the_reference_controllers_act_on_observation_batches():
    from ibt.runs.reference_controllers import references

    for ref in references():
        task = get_task(ref.task)
        obs = np.random.default_rng(0).uniform(0.1, 0.6, size=(3, task.n_features))
        actions = np.asarray(ref.act(obs))
        assert len(actions) == 3
        if task.continuous:
            assert actions.shape == (3, task.n_actions) and np.isfinite(actions).all()


# ------------------------------------------------------------------- oblique (discrete) trees
def test_an_oblique_tree_finds_a_test_of_three_features_in_one_split():
    from ibt.distill.oblique import fit_oblique_tree

    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 1, size=(4000, 5)).astype(np.float32)
    y = (0.5 * x[:, 0] + x[:, 2] - x[:, 3] > 0.1).astype(np.int64)
    tree = fit_oblique_tree(x, y, n_classes=2, max_leaves=2)
    # Expect: one oblique split on features 0, 2, 3 that classifies almost every state
    assert tree.n_leaves == 2 and set(np.flatnonzero(tree.split[0])) <= {0, 2, 3}
    assert np.mean(tree.decide(x) == y) > 0.97


def test_an_oblique_bt_decides_exactly_as_its_tree_in_ibt_and_in_behaviortree_cpp():
    from ibt.distill.oblique import ObliqueArrays
    from ibt.export.btcpp import to_btcpp_xml
    from ibt.export.engine import EngineTree

    task = get_task("LunarLander-v3")
    split = np.zeros((5, 8))
    split[0, [0, 2, 4]] = (0.5, 1.0, -1.0)
    split[1, 6] = 1.0
    tree = ObliqueArrays(np.array([1, 3, -1, -1, -1]), np.array([2, 4, -1, -1, -1]), split,
                         np.array([0.05, 0.5, 0, 0, 0]), np.array([-1, -1, 2, 0, 1]))
    rng = np.random.default_rng(4)
    states = check_states(tree, task, rng.normal(size=(300, 8)), n_random=300)
    built = controller_bt(tree, task, states)
    assert built.rules == 3 and built.bt.commands is None
    engine = EngineTree(to_btcpp_xml(built.bt), task.feature_names, task.action_names)
    # Expect: the engine's decisions are the tree's on every state
    assert np.array_equal(engine.decide(states), tree.decide(states))


def test_refinement_by_return_is_deterministic_and_keeps_the_shape():
    from ibt.refine.controller import refine_controller
    from ibt.tasks.settings import RefineConfig

    task = get_task("Pendulum-v1")
    rng = np.random.default_rng(5)
    tree = _controller(rng, n_features=3, n_dims=1, oblique=False)
    config = RefineConfig(stages=("cma",), episodes=24, cma_generations=2, cma_episodes=2,
                          cma_popsize=4, sweep_episodes=2, selection_episodes=3, n_envs=8)
    first = refine_controller(tree, task, config, seed=1, progress=False)
    again = refine_controller(tree, task, config, seed=1, progress=False)
    assert first.to_doc()["candidates"] == again.to_doc()["candidates"]
    best = first.candidates[first.best_index]
    assert np.array_equal(best.left, tree.left)
    assert np.array_equal(best.weights != 0, tree.weights != 0) or first.stages[-1].get("digits")


def test_a_tree_with_nothing_to_tune_is_kept_as_it_is():
    from ibt.distill.oblique import ObliqueArrays
    from ibt.refine.controller import refine_controller
    from ibt.tasks.settings import RefineConfig

    task = get_task("CartPole-v1")
    one_leaf = ObliqueArrays(np.array([-1]), np.array([-1]), np.zeros((1, 4)), np.zeros(1),
                             np.array([1]))
    config = RefineConfig(stages=("cma",), episodes=8, cma_episodes=2, selection_episodes=2,
                          n_envs=4)
    record = refine_controller(one_leaf, task, config, progress=False)
    assert record.stages[0]["generations"] == 0
    assert np.array_equal(record.candidates[record.best_index].action, one_leaf.action)


@given(st.integers(1, 200), st.integers(1, 12), st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_best_first_growth_partitions_the_rows_and_splits_the_largest_gain_first(
        n_rows, max_leaves, seed):
    """The growth both learners share: children partition their parent's rows, at most
    ``max_leaves`` leaves, every split taken had the largest gain on offer (the leaf made
    first on a tie), and growth stops only at the limit or where no leaf can split."""
    rng = np.random.default_rng(seed)
    values = rng.normal(size=n_rows)
    gains = rng.integers(0, 3, size=n_rows)  # ties are common

    def propose(rows):
        if len(rows) < 2:
            return None
        return float(gains[rows].sum()), None, float(np.median(values[rows]))

    taken = []

    def goes_left(rows, _, threshold):
        taken.append(float(gains[rows].sum()))
        left = values[rows] <= threshold
        return left if 0 < left.sum() < len(rows) else np.arange(len(rows)) < len(rows) // 2

    nodes = grow_best_first(n_rows, max_leaves, propose, goes_left)
    leaves = [n for n in nodes if "split" not in n]
    assert len(leaves) <= max_leaves
    for node in nodes:
        if "split" in node:
            children = np.concatenate([nodes[node["left"]]["rows"], nodes[node["right"]]["rows"]])
            assert sorted(children) == sorted(node["rows"])
    assert sorted(np.concatenate([n["rows"] for n in leaves])) == list(range(n_rows))
    if len(leaves) < max_leaves:
        assert all(len(n["rows"]) < 2 for n in leaves)
    split_order = [n for n in range(len(nodes)) if "split" in nodes[n]]
    assert len(taken) == len(split_order)
    # each split had the largest gain among the leaves on offer at its turn
    offered = {0}
    for gain, node in zip(taken, sorted(split_order, key=lambda k: nodes[k]["left"]), strict=True):
        on_offer = [float(gains[nodes[n]["rows"]].sum()) for n in sorted(offered)
                    if len(nodes[n]["rows"]) >= 2]
        assert gain == max(on_offer)
        first = min(n for n in sorted(offered) if len(nodes[n]["rows"]) >= 2
                    and float(gains[nodes[n]["rows"]].sum()) == gain)
        assert node == first
        offered.remove(node)
        offered |= {nodes[node]["left"], nodes[node]["right"]}


@given(st.integers(1, 60), st.integers(1, 5), st.integers(1, 3), st.integers(1, 40),
       st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_the_split_searchs_running_sums_held_a_block_at_a_time_are_one_running_sum(
        n_rows, n_features, n_dims, block, seed):
    """Bounded memory without a changed bit: the running sums of ``z z^T``, ``z y^T`` and
    ``y . y`` read at any rows, a few rows at a time, equal NumPy's one running sum over all
    rows exactly, and so do the sums resumed from a carry."""
    import ibt.distill.controller as controller

    rng = np.random.default_rng(seed)
    zs, ys = rng.normal(size=(n_rows, n_features)) * 1e3, rng.normal(size=(n_rows, n_dims))
    whole = (np.cumsum(zs[:, :, None] * zs[:, None, :], axis=0),
             np.cumsum(zs[:, :, None] * ys[:, None, :], axis=0), np.cumsum((ys * ys).sum(axis=1)))
    sums = controller._RunningSums(zs, ys)
    sums.block = block
    rows = np.unique(rng.integers(0, n_rows, size=rng.integers(1, n_rows + 1)))
    for got, want in zip(sums.at(rows), whole, strict=True):
        assert np.array_equal(got, want[rows])
    start = int(rows[0]) + 1
    later = rows[rows >= start - 1]
    resumed = sums.at(later, start, tuple(w[start - 1] for w in whole))
    for got, want in zip(resumed, whole, strict=True):
        assert np.array_equal(got, want[later])


def test_a_model_tree_is_the_same_whatever_the_block_of_its_running_sums(monkeypatch):
    import ibt.distill.controller as controller

    rng = np.random.default_rng(3)
    x = rng.normal(size=(900, 5)).astype(np.float32)
    y = np.tanh(x[:, :2] @ np.array([[1.0, -0.5], [0.3, 2.0]]) + (x[:, 2:3] > 0.2))
    default = fit_model_tree(x, y, 6)
    monkeypatch.setattr(controller, "BLOCK_BYTES", 3000)  # a few rows a block
    small = fit_model_tree(x, y, 6)
    for name in ("left", "right", "split", "threshold", "bias", "weights"):
        assert np.array_equal(getattr(default, name), getattr(small, name)), name
