"""BehaviorTree.CPP v4 export: well-formed, self-describing, exact round trip."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from ibt.baselines import bt_espresso, re_bt_espresso
from ibt.bt import Action, BehaviorTree, Condition, Fallback, Inverter, Selector, Sequence
from ibt.btcpp import action_ids, from_btcpp_xml, to_btcpp_xml
from ibt.synthesis import imitation_bt
from ibt.tasks import get_task
from tests.conftest import fit_tree
from tests.test_synthesis import TOY

METHODS = {"imitation-bt": imitation_bt, "bt-espresso": bt_espresso,
           "re-bt-espresso": re_bt_espresso}


@pytest.fixture(scope="module")
def trees():
    return [fit_tree(leaves=leaves, n_actions=4, seed=seed, n=600)[0]
            for seed, leaves in [(0, 4), (1, 12), (2, 25)]]


@pytest.mark.parametrize("method", sorted(METHODS))
def test_round_trip_is_identity(method, trees):
    for tree in trees:
        bt = METHODS[method](tree, TOY, check=False).bt
        back = from_btcpp_xml(to_btcpp_xml(bt), bt.feature_names, bt.action_names)
        assert back == bt
        states = np.random.default_rng(0).uniform(-1, 1, (500, 4)).astype(np.float32)
        assert np.array_equal(back.decide(states), tree.predict(states))


@pytest.mark.parametrize("method", sorted(METHODS))
def test_xml_structure(method, trees):
    bt = METHODS[method](trees[1], TOY, check=False).bt
    text = to_btcpp_xml(bt, tree_id="Policy")
    root = ET.fromstring(text)  # well-formed
    assert root.tag == "root"
    assert root.attrib == {"BTCPP_format": "4", "main_tree_to_execute": "Policy"}
    [tree] = root.findall("BehaviorTree")
    assert tree.get("ID") == "Policy" and len(tree) == 1
    assert sum(1 for _ in tree.iter()) - 1 == bt.node_count  # one element per node
    assert {e.tag for e in tree.iter()} - {"BehaviorTree"} <= {
        "Fallback", "Sequence", "Inverter", "Condition", "Action"}
    model = root.find("TreeNodesModel")
    assert model is not None
    [condition] = model.findall("Condition")
    assert condition.get("ID") == "CheckFeature"
    ports = {p.get("name"): p.get("type") for p in condition.findall("input_port")}
    assert ports == {"feature": "int", "op": "std::string", "threshold": "double"}
    declared = {a.get("ID") for a in model.findall("Action")}
    assert declared == set(TOY.action_names)
    for element in tree.iter("Condition"):
        assert element.get("ID") == "CheckFeature"
        assert set(element.attrib) == {"ID", "name", "feature", "op", "threshold"}
    for element in tree.iter("Action"):
        assert element.get("ID") in declared and set(element.attrib) == {"ID"}


def test_thresholds_full_precision_and_ops_escaped():
    threshold = 0.1 + 0.2  # 0.30000000000000004: any rounding would lose it
    bt = BehaviorTree(Selector((Sequence((Condition(2, ">", threshold), Action(1))),
                                Action(0))),
                      get_task("CartPole-v1").feature_names, get_task("CartPole-v1").action_names)
    text = to_btcpp_xml(bt)
    assert 'threshold="0.30000000000000004"' in text
    assert 'op="&gt;"' in text and 'name="pole_angle &gt; 0.3"' in text
    assert '<Action ID="push_right" />' in text
    back = from_btcpp_xml(text, bt.feature_names, bt.action_names)
    assert back.root.children[0].children[0].threshold == threshold
    assert back == bt


def test_selector_and_fallback_stay_distinct():
    inner = Fallback((Condition(0, "<=", 1.5), Inverter(Condition(1, "<=", -0.25))))
    bt = BehaviorTree(Selector((Sequence((inner, Action(0))), Action(1))), ("a", "b"),
                      ("go", "stop"))
    back = from_btcpp_xml(to_btcpp_xml(bt), bt.feature_names, bt.action_names)
    assert type(back.root) is Selector
    assert type(back.root.children[0].children[0]) is Fallback
    assert back == bt


def test_action_ids_are_identifiers_and_unique():
    names = ("push left", "push-left", "1up", "CheckFeature", "ok")
    ids = action_ids(names)
    assert len(set(ids)) == len(ids)
    assert all(i.isidentifier() for i in ids)
    assert ids[-1] == "ok"
    bt = BehaviorTree(Selector(tuple(Action(i) for i in range(5))), ("x",), names)
    assert from_btcpp_xml(to_btcpp_xml(bt), ("x",), names) == bt


def test_unknown_nodes_are_rejected():
    text = ('<root BTCPP_format="4" main_tree_to_execute="MainTree"><BehaviorTree ID="MainTree">'
            '<Parallel><Action ID="go"/></Parallel></BehaviorTree></root>')
    with pytest.raises(ValueError, match="Parallel"):
        from_btcpp_xml(text, ("x",), ("go",))
    with pytest.raises(ValueError, match="unknown action"):
        from_btcpp_xml(text.replace("Parallel", "Sequence").replace('"go"', '"jump"'),
                       ("x",), ("go",))
    with pytest.raises(ValueError, match="no <BehaviorTree"):
        from_btcpp_xml(text, ("x",), ("go",), tree_id="Other")
