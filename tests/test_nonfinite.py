"""NaN and infinity have one meaning: every executor refuses them (``ibt.bt.executors``).

The compiled tree, the tree policy, the BT's ``decide``, ``tick`` and py_trees executors and the
BehaviorTree.CPP engine raise :class:`NonFiniteObservation` on the same inputs; on finite
inputs they agree, and a BT that passed ``validate()`` never returns "no action".
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.executors import NonFiniteObservation, decide_batch, py_trees_decide, tick, to_py_trees
from ibt.bt.model import NO_DECISION
from ibt.evaluate.policies import CompiledTree
from ibt.export.btcpp import to_btcpp_xml
from ibt.synth.imitation import imitation_bt, verify
from ibt.tasks.catalogue import get_task


@pytest.fixture(scope="module")
def pair():
    task = get_task("CartPole-v1")
    rng = np.random.default_rng(3)
    x = rng.normal(size=(400, 4)).astype(np.float32)
    y = (x[:, 2] + 0.5 * x[:, 3] > 0).astype(int)
    tree = DecisionTreeClassifier(max_leaf_nodes=6, random_state=0).fit(x, y)
    bt = imitation_bt(tree, task).bt
    bt.validate()
    engine = None
    try:
        from ibt.export.engine import load_engine_tree

        engine = load_engine_tree(to_btcpp_xml(bt), task)
    except ImportError:  # behaviortreepy missing: the engine is checked where it is installed
        pass
    return task, tree, bt, engine


def _executors(tree, bt, engine):
    compiled = CompiledTree(tree)
    root, io = to_py_trees(bt)
    run = {"compiled tree (small batch)": lambda x: compiled.predict(x),
           "compiled tree (vector)": lambda x: compiled.predict(np.repeat(x, 70, axis=0))[:1],
           "BT decide": lambda x: bt.decide(x),
           "BT decide_batch": lambda x: decide_batch(bt.root, x),
           "BT tick": lambda x: np.array([tick(bt, x[0])[0]]),
           "py_trees": lambda x: py_trees_decide(root, io, x)}
    if engine is not None:
        run["BehaviorTree.CPP engine"] = lambda x: engine.decide(x)
    return run


FIXTURE = [HealthCheck.function_scoped_fixture]  # the fixture is module-scoped: no state
_finite = st.floats(-1e6, 1e6, allow_nan=False, width=32)
_bad = st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300])


@settings(max_examples=60, deadline=None, suppress_health_check=FIXTURE)
@given(values=st.lists(_finite, min_size=4, max_size=4), bad=_bad, where=st.integers(0, 3))
def test_every_executor_refuses_nan_and_infinity(pair, values, bad, where):
    _, tree, bt, engine = pair
    x = np.array([values], dtype=np.float64)
    x[0, where] = bad
    for name, run in _executors(tree, bt, engine).items():
        with pytest.raises(NonFiniteObservation, match=f"feature {where}"):
            run(x)
        assert name


@settings(max_examples=100, deadline=None, suppress_health_check=FIXTURE)
@given(values=st.lists(_finite, min_size=4, max_size=4))
def test_on_finite_states_every_executor_agrees_and_acts(pair, values):
    _, tree, bt, engine = pair
    x = np.array([values], dtype=np.float64)
    decisions = {name: int(run(x)[0]) for name, run in _executors(tree, bt, engine).items()}
    assert len(set(decisions.values())) == 1, decisions
    assert NO_DECISION not in decisions.values()


def test_the_verifier_checks_finite_states_and_the_policies_refuse(pair):
    from ibt.evaluate.policies import BTPolicy, TreePolicy
    from ibt.synth.imitation import verification_states

    task, tree, bt, _ = pair
    states = verification_states(tree, task, n_random=500)
    assert np.isfinite(states).all() and verify(bt, tree, task, n_random=500) == len(states)
    obs = np.zeros((2, 4))
    obs[1, 2] = np.nan
    for policy in (TreePolicy(task, tree), BTPolicy(task, bt)):
        with pytest.raises(NonFiniteObservation, match="feature 2 of row 1"):
            policy.act(obs)
