"""The compiled Python BT decides exactly as the BT; drawings and traces render."""

from __future__ import annotations

import numpy as np
import pytest

from ibt.bt import Action, BehaviorTree, Condition, Selector, Sequence
from ibt.export import require_dot, to_graphviz, trace_graph
from ibt.speed import NotCompilable, compile_python
from ibt.synthesis import imitation_bt
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
    assert source.count("->") == bt.node_count - 1
    assert to_graphviz(bt).source.count("label=") == bt.node_count


def test_missing_dot_names_the_fix(monkeypatch):
    monkeypatch.setattr("shutil.which", lambda name: None)
    with pytest.raises(RuntimeError, match="apt-get install graphviz"):
        require_dot()
