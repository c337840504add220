"""BehaviorTree.CPP v4 XML: both flavours well-formed and self-describing, exact round trips,
deterministic blackboard keys and action IDs. (The engine itself: test_btcpp_engine.py.)"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Inverter, Selector, Sequence
from ibt.export.btcpp import (
    BUILTIN_IDS,
    FLAVOURS,
    action_ids,
    blackboard_keys,
    from_btcpp_xml,
    threshold_text,
    to_btcpp_xml,
)
from ibt.synth.baselines import bt_espresso, re_bt_espresso
from ibt.synth.imitation import imitation_bt
from ibt.tasks.catalogue import TASKS, get_task
from tests.conftest import fit_tree
from tests.test_synthesis import TOY

METHODS = {"imitation-bt": imitation_bt, "bt-espresso": bt_espresso,
           "re-bt-espresso": re_bt_espresso}


@pytest.fixture(scope="module")
def trees():
    return [fit_tree(leaves=leaves, n_actions=4, seed=seed, n=600)[0]
            for seed, leaves in [(0, 4), (1, 12), (2, 25)]]


def _bt(root, features=("a", "b"), actions=("go", "stop")) -> BehaviorTree:
    return BehaviorTree(root, tuple(features), tuple(actions))


@pytest.mark.parametrize("flavour", FLAVOURS)
@pytest.mark.parametrize("method", sorted(METHODS))
def test_round_trip_is_identity(method, flavour, trees):
    for tree in trees:
        bt = METHODS[method](tree, TOY, check=False).bt
        back = from_btcpp_xml(to_btcpp_xml(bt, flavour=flavour), bt.feature_names,
                              bt.action_names)
        assert back == bt
        states = np.random.default_rng(0).uniform(-1, 1, (500, 4)).astype(np.float32)
        assert np.array_equal(back.decide(states), tree.predict(states))


def _parts(text: str):
    root = ET.fromstring(text)  # well-formed
    assert root.tag == "root"
    assert root.attrib == {"BTCPP_format": "4"}  # no main_tree_to_execute: Groot2 drops it
    [tree] = root.findall("BehaviorTree")
    model = root.find("TreeNodesModel")
    assert model is not None
    return tree, model


@pytest.mark.parametrize("method", sorted(METHODS))
def test_portable_structure(method, trees):
    bt = METHODS[method](trees[1], TOY, check=False).bt
    text = to_btcpp_xml(bt, tree_id="Policy")
    assert text.startswith('<?xml version="1.0" encoding="UTF-8"?>\n')
    tree, model = _parts(text)
    assert tree.get("ID") == "Policy" and len(tree) == 1
    assert sum(1 for _ in tree.iter()) - 1 == bt.node_count  # one element per node
    assert {e.tag for e in tree.iter()} - {"BehaviorTree"} <= {
        "Fallback", "Sequence", "Inverter", "ScriptCondition", "Action"}
    assert [a.get("ID") for a in model] == list(TOY.action_names)  # actions only: nothing custom
    assert all(a.tag == "Action" and not len(a) for a in model)
    conditions = list(tree.iter("ScriptCondition"))
    assert len(conditions) == sum(isinstance(n, Condition) for n in bt.nodes())
    for element in conditions:
        assert set(element.attrib) == {"code", "name"}
        key, op, number = element.get("code").split()
        assert key in TOY.feature_names and op in ("<=", ">")
        assert element.get("name").startswith(f"{key} {op} ")
        float(number)
    for element in tree.iter("Action"):
        assert set(element.attrib) == {"ID"}


@pytest.mark.parametrize("method", sorted(METHODS))
def test_check_feature_structure(method, trees):
    bt = METHODS[method](trees[1], TOY, check=False).bt
    tree, model = _parts(to_btcpp_xml(bt, flavour="check-feature"))
    [condition] = model.findall("Condition")
    assert condition.get("ID") == "CheckFeature"
    ports = {p.get("name"): p.get("type") for p in condition.findall("input_port")}
    assert ports == {"feature": "int", "op": "std::string", "threshold": "double"}
    assert {a.get("ID") for a in model.findall("Action")} == set(TOY.action_names)
    assert not list(tree.iter("ScriptCondition"))
    for element in tree.iter("Condition"):
        assert element.get("ID") == "CheckFeature"
        assert set(element.attrib) == {"ID", "name", "feature", "op", "threshold"}


def test_thresholds_full_precision_and_ops_escaped():
    threshold = 0.1 + 0.2  # 0.30000000000000004: any rounding would lose it
    task = get_task("CartPole-v1")
    bt = BehaviorTree(Selector((Sequence((Condition(2, ">", threshold), Action(1))),
                                Action(0))), task.feature_names, task.action_names)
    text = to_btcpp_xml(bt)
    assert 'code="pole_angle &gt; 0.30000000000000004"' in text
    assert 'name="pole_angle &gt; 0.3"' in text
    assert '<Action ID="push_right" />' in text
    assert "pole_angle = double(float(obs[2]))" in text  # the comment lists the keys
    back = from_btcpp_xml(text, bt.feature_names, bt.action_names)
    assert back.root.children[0].children[0].threshold == threshold
    assert back == bt
    check = to_btcpp_xml(bt, flavour="check-feature")
    assert 'threshold="0.30000000000000004"' in check and 'op="&gt;"' in check
    assert from_btcpp_xml(check, bt.feature_names, bt.action_names) == bt


def test_categorical_conditions_are_exact_with_readable_names():
    task = get_task("PackageDelivery-v0")
    carrying = task.feature_names.index("carrying")
    bt = BehaviorTree(Selector((Sequence((Condition(carrying, ">", 1.5), Action(5))),
                                Action(7))), task.feature_names, task.action_names,
                      task.value_labels)
    text = to_btcpp_xml(bt)
    assert 'code="carrying &gt; 1.5" name="carrying == heavy"' in text
    assert from_btcpp_xml(text, task.feature_names, task.action_names,
                          value_labels=task.value_labels) == bt


@settings(max_examples=300, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from(["<=", ">"]))
def test_every_finite_threshold_round_trips(threshold, op):
    """Law: any double threshold reads back unchanged, except subnormals (which std::stod
    rejects), which become a float32 value deciding alike on every float32 input."""
    bt = _bt(Selector((Sequence((Condition(1, op, threshold), Action(1))), Action(0))))
    for flavour in FLAVOURS:
        back = from_btcpp_xml(to_btcpp_xml(bt, flavour=flavour), bt.feature_names,
                              bt.action_names)
        written = back.root.children[0].children[0].threshold
        if threshold == 0.0 or abs(threshold) >= sys.float_info.min:
            assert written == threshold and back == bt
        else:
            probes = np.array([-1.4e-45, -0.0, 0.0, 1.4e-45, 2.8e-45], dtype=np.float32)
            x = np.column_stack([probes, probes])
            assert np.array_equal(back.decide(x), bt.decide(x))


def test_subnormal_thresholds_and_non_finite_ones():
    assert threshold_text(5e-324) == "0.0"
    assert threshold_text(-5e-324) == repr(float(np.float32(-1.4e-45)))
    assert threshold_text(sys.float_info.min) == repr(sys.float_info.min)
    assert threshold_text(-0.0) == "-0.0"
    with pytest.raises(ValueError, match="not finite"):
        threshold_text(float("inf"))


def test_selector_and_fallback_stay_distinct():
    inner = Fallback((Condition(0, "<=", 1.5), Inverter(Condition(1, "<=", -0.25))))
    bt = _bt(Selector((Sequence((inner, Action(0))), Action(1))))
    for flavour in FLAVOURS:
        back = from_btcpp_xml(to_btcpp_xml(bt, flavour=flavour), bt.feature_names,
                              bt.action_names)
        assert type(back.root) is Selector
        assert type(back.root.children[0].children[0]) is Fallback
        assert back == bt


def test_blackboard_keys_are_identifiers_unique_and_deterministic():
    names = ("speed", "speed (m/s)", "speed__m_s_", "1st", "true_north", "falsey", "_x",
             "x.y", "x y", "", "é", "True")
    keys = blackboard_keys(names)
    assert keys == ["speed", "speed__m_s_", "speed__m_s__2", "f_1st", "f_true_north",
                    "f_falsey", "f__x", "x_y", "x_y_8", "f_", "f__", "True"]
    assert len(set(keys)) == len(keys)
    assert all(k.isidentifier() and k[0].isalpha() and k.isascii() for k in keys)
    assert blackboard_keys(names) == keys


def test_every_registered_task_keeps_its_feature_names_as_keys():
    """The README says so: no task of ours needs renaming."""
    for task in TASKS.values():
        assert blackboard_keys(task.feature_names) == list(task.feature_names), task.name


def test_action_ids_are_identifiers_unique_and_not_builtin():
    names = ("push left", "push-left", "1up", "CheckFeature", "Sequence", "ScriptCondition",
             "ok")
    ids = action_ids(names)
    assert ids == ["push_left", "push_left_1", "_1up", "CheckFeature_3", "Sequence_4",
                   "ScriptCondition_5", "ok"]
    assert not set(ids) & BUILTIN_IDS
    bt = BehaviorTree(Selector(tuple(Action(i) for i in range(len(names)))), ("x",), names)
    for flavour in FLAVOURS:
        assert from_btcpp_xml(to_btcpp_xml(bt, flavour=flavour), ("x",), names) == bt


def test_odd_feature_names_round_trip():
    names = ("speed (m/s)", "1st", "true_north", "x.y", "x y")
    root = Selector((*(Sequence((Condition(i, ">", i * 0.5), Action(1))) for i in range(5)),
                     Action(0)))
    bt = _bt(root, names)
    text = to_btcpp_xml(bt)
    assert 'code="f_true_north &gt; 1.0"' in text and 'name="true_north &gt; 1"' in text
    assert from_btcpp_xml(text, names, bt.action_names) == bt


def test_groot2_compact_nodes_and_main_tree_attribute_are_read():
    text = ('<root BTCPP_format="4" main_tree_to_execute="B"><BehaviorTree ID="A"><stop/>'
            '</BehaviorTree><BehaviorTree ID="B"><Fallback name="Selector"><Sequence>'
            '<Condition ID="ScriptCondition" code="b &lt;= -2.5e-07"/><go/></Sequence>'
            '<Action ID="stop"/></Fallback></BehaviorTree></root>')
    bt = from_btcpp_xml(text, ("a", "b"), ("go", "stop"))
    assert bt == _bt(Selector((Sequence((Condition(1, "<=", -2.5e-07), Action(0))),
                               Action(1))))
    assert from_btcpp_xml(text, ("a", "b"), ("go", "stop"), tree_id="A").root == Action(1)


def test_unknown_nodes_and_other_tasks_are_rejected():
    text = ('<root BTCPP_format="4"><BehaviorTree ID="MainTree">'
            '<Parallel><Action ID="go"/></Parallel></BehaviorTree></root>')
    with pytest.raises(ValueError, match="Parallel"):
        from_btcpp_xml(text, ("x",), ("go",))
    with pytest.raises(ValueError, match="unknown action ID 'jump'; this task's actions are go"):
        from_btcpp_xml(text.replace("Parallel", "Sequence").replace('"go"', '"jump"'),
                       ("x",), ("go",))
    with pytest.raises(ValueError, match="no <BehaviorTree ID='Other'"):
        from_btcpp_xml(text, ("x",), ("go",), tree_id="Other")
    script = ('<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
              '<ScriptCondition code="CODE"/><Action ID="go"/></Sequence></BehaviorTree></root>')
    with pytest.raises(ValueError, match=r"key 'velocity'.*another task"):
        from_btcpp_xml(script.replace("CODE", "velocity &gt; 1"), ("x",), ("go",))
    with pytest.raises(ValueError, match="unsupported ScriptCondition code"):
        from_btcpp_xml(script.replace("CODE", "x &gt; 1 &amp;&amp; x &lt; 2"), ("x",), ("go",))
    with pytest.raises(ValueError, match="not a number"):
        from_btcpp_xml(script.replace("CODE", "x &gt; one"), ("x",), ("go",))
    with pytest.raises(ValueError, match="well-formed"):
        from_btcpp_xml("<root>", ("x",), ("go",))
    two = text.replace("</root>", '<BehaviorTree ID="B"><Action ID="go"/></BehaviorTree></root>')
    with pytest.raises(ValueError, match="2 trees"):
        from_btcpp_xml(two, ("x",), ("go",))
    with pytest.raises(ValueError, match="flavour"):
        to_btcpp_xml(_bt(Action(0)), flavour="groot")
