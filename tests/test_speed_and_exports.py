"""The compiled Python BT decides exactly as the BT; drawings and traces render."""

from __future__ import annotations

import numpy as np
import pytest

from ibt.bt.model import Action, BehaviorTree, Condition, Selector, Sequence
from ibt.evaluate.speed import NotCompilable, compile_python
from ibt.export.drawing import drawing_elements, require_dot, to_graphviz, trace_graph
from ibt.synth.imitation import imitation_bt
from tests.conftest import fit_tree
from tests.test_synthesis import TOY


@pytest.mark.parametrize("seed", range(5))
def test_compiled_python_equals_the_bt(seed):
    tree, _ = fit_tree(leaves=20, n_actions=4, seed=seed)
    bt = imitation_bt(tree, TOY).bt
    decide = compile_python(bt)
    states = np.random.default_rng(seed).uniform(-1.2, 1.2, size=(2000, 4)).astype(np.float32)
    assert [decide(s) for s in states] == bt.decide(states).tolist()


def test_compiler_refuses_shapes_it_does_not_know():
    odd = BehaviorTree(Selector((Sequence((Action(0), Condition(0, "<=", 0.0))), Action(1))),
                       ("a",), ("x", "y"))
    with pytest.raises(NotCompilable):
        compile_python(odd)


def test_trace_drawing_highlights_ticked_nodes():
    tree, _ = fit_tree(leaves=6, n_actions=2)
    bt = imitation_bt(tree, TOY).bt
    source = trace_graph(bt, [0.0, 0.0, 0.0, 0.0]).source
    assert "penwidth=3" in source
    assert "◆" in source  # the deciding condition is marked
    assert sorted(drawing_elements(bt)) == list(range(bt.node_count))
    assert "✓" not in to_graphviz(bt).source


def test_missing_dot_names_the_fix(monkeypatch):
    monkeypatch.setattr("shutil.which", lambda name: None)
    with pytest.raises(RuntimeError, match="apt-get install graphviz"):
        require_dot()


def test_small_batches_walk_the_tree_exactly_as_sklearn():
    import numpy as np
    from sklearn.tree import DecisionTreeClassifier

    from ibt.evaluate.policies import SMALL_BATCH, CompiledTree

    rng = np.random.default_rng(1)
    x = rng.normal(size=(3000, 5)).astype(np.float32)
    y = (x[:, 0] * x[:, 1] > 0).astype(int) + (x[:, 2] > 0.3)
    tree = DecisionTreeClassifier(max_leaf_nodes=40, random_state=0).fit(x, y)
    probe = rng.normal(size=(SMALL_BATCH * 20, 5)).astype(np.float32)
    inner = tree.tree_.feature >= 0
    splits = zip(tree.tree_.feature[inner], tree.tree_.threshold[inner], strict=True)
    for k, (f, t) in enumerate(splits):
        probe[k, f] = np.float32(t)  # exactly on split points
    compiled = CompiledTree(tree)
    small = np.concatenate([compiled.predict(probe[i:i + 7]) for i in range(0, len(probe), 7)])
    assert np.array_equal(small, tree.predict(probe))
    assert np.array_equal(compiled.predict(probe), tree.predict(probe))


def test_executors_agree_on_random_states_and_catch_a_wrong_bt():
    from ibt.evaluate.speed import executors_agree

    tree, _ = fit_tree(leaves=12, n_actions=3, seed=3)
    bt = imitation_bt(tree, TOY).bt
    states = np.random.default_rng(0).uniform(-1.2, 1.2, size=(5000, 4)).astype(np.float32)
    assert executors_agree(bt, tree, states, py_trees_states=500)
    wrong = BehaviorTree(Selector((Action(0),)), bt.feature_names, bt.action_names)
    assert not executors_agree(wrong, tree, states, py_trees_states=100)


@pytest.mark.parametrize("name", ["CartPole-v1", "FrozenLake-v1", "PackageDelivery-v0"])
def test_observations_invert_features(name):
    import ibt

    task = ibt.get_task(name)
    x = task.sample_features(50, np.random.default_rng(0))
    obs = task.observations(x)
    assert np.array_equal(task.features(obs), x)
