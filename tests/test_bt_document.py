"""A Behavior Tree's JSON document (:mod:`ibt.bt.document`): written with the format and the
tick rule its nodes need, read back to the same tree, and read strictly, every refusal one line
that says where (``root.children[1]``) and what."""

from __future__ import annotations

import json
import re

import pytest

from ibt.bt import document
from ibt.bt.document import (
    FORMAT,
    FORMAT_LINEAR,
    LINEAR_TICK_RULE,
    RELATIONAL_TICK_RULE,
    TICK_RULE,
    node_from_dict,
    node_to_dict,
    strict_json,
    tree_from_dict,
    tree_to_dict,
)
from ibt.bt.linear import LinearForm, ObliqueForm
from ibt.bt.model import (
    MAX_DEPTH,
    Action,
    BehaviorTree,
    Commands,
    Condition,
    Fallback,
    Inverter,
    Selector,
    Sequence,
)

ROOT = Selector((Sequence((Condition(0, ">", 1.0), Action(1))), Action(0)))


def _bt(root=ROOT, **kwargs) -> BehaviorTree:
    return BehaviorTree(root, ("a", "b"), ("x", "y"), **kwargs)


def _doc(**changes) -> dict:
    doc = tree_to_dict(_bt())
    doc.update(changes)
    return {k: v for k, v in doc.items() if v is not None}


def _refused(doc, words: str) -> None:
    with pytest.raises(ValueError, match=re.escape(words)):
        tree_from_dict(BehaviorTree, doc)


# ---------------------------------------------------------------------------- strict JSON
def test_strict_json_reads_text_and_utf8_bytes():
    assert strict_json('{"a": [1, 2]}') == {"a": [1, 2]}
    assert strict_json('{"é": 1}'.encode()) == {"é": 1}
    assert strict_json("NaN") != strict_json("NaN")  # read; its reader says it must be finite


@pytest.mark.parametrize("text, words", [
    ('{"a": 1, "a": 2}', "not strict JSON (duplicate key 'a')"),
    ('{"a": {"b": 1, "b": 1}}', "not strict JSON (duplicate key 'b')"),
    (b'{"a": "\xe9"}', "not strict JSON ('utf-8' codec can't decode byte 0xe9"),
    ('{"a": ', "not strict JSON (Expecting value"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply to be a behavior tree"),
])
def test_strict_json_refuses_in_one_line(text, words):
    with pytest.raises(ValueError) as err:
        strict_json(text)
    assert str(err.value).startswith(words) and "\n" not in str(err.value)


def test_a_duplicate_key_is_named_and_cut_short():
    with pytest.raises(ValueError, match=r"^duplicate key 'kkkk") as err:
        document.no_duplicate_keys([("k" * 100, 1), ("k" * 100, 2)])
    assert len(str(err.value)) < 80
    assert document.no_duplicate_keys([("a", 1), ("b", 2)]) == {"a": 1, "b": 2}


# -------------------------------------------------------------------------------- writing
def test_an_axis_aligned_bt_is_format_1_with_the_plain_rule():
    doc = tree_to_dict(_bt())
    assert doc == {"format": FORMAT, "feature_names": ["a", "b"], "action_names": ["x", "y"],
                   "tick_rule": TICK_RULE,
                   "root": {"type": "selector", "children": [
                       {"type": "sequence", "children": [
                           {"type": "condition", "feature": 0, "op": ">", "threshold": 1.0},
                           {"type": "action", "action": 1}]},
                       {"type": "action", "action": 0}]}}
    assert tree_from_dict(BehaviorTree, doc) == _bt()


def test_a_relational_bt_is_format_1_with_the_relational_rule():
    root = Selector((Sequence((Condition.relational(LinearForm(0, 1), "<=", 0.5), Action(1))),
                     Action(0)))
    doc = tree_to_dict(_bt(root))
    assert doc["format"] == FORMAT and doc["tick_rule"] == TICK_RULE + RELATIONAL_TICK_RULE
    assert doc["root"]["children"][0]["children"][0] == {
        "type": "condition", "form": {"features": [0, 1], "weights": [1.0, -1.0]}, "op": "<=",
        "threshold": 0.5}
    assert tree_from_dict(BehaviorTree, doc) == _bt(root)
    assert not document.needs_linear_format(_bt(root))


def test_an_oblique_bt_is_format_2_with_the_linear_rule_and_format_1_refuses_it():
    oblique = Condition.relational(ObliqueForm((0,), (2.0,)), "<=", 0.5)
    bt = _bt(Selector((Sequence((oblique, Action(1))), Action(0))))
    assert document.needs_linear_format(bt)
    doc = tree_to_dict(bt)
    assert doc["format"] == FORMAT_LINEAR and doc["tick_rule"] == TICK_RULE + LINEAR_TICK_RULE
    assert tree_from_dict(BehaviorTree, doc) == bt
    assert BehaviorTree.from_json(json.dumps(doc)) == bt  # read from text: new strings
    _refused({**doc, "format": FORMAT, "tick_rule": TICK_RULE},
             f"is format {FORMAT_LINEAR!r}; write that format")
    _refused({**doc, "tick_rule": TICK_RULE + RELATIONAL_TICK_RULE}, "its tick_rule is not")
    _refused({**doc, "tick_rule": TICK_RULE}, "its tick_rule is not")


def test_commands_and_value_labels_are_written_and_read_back():
    constant = Commands(("throttle",), ("unit",), ((0.0,), (1.0,)))
    bt = _bt(value_labels=((1, ("off", "on")),), commands=constant)
    doc = tree_to_dict(bt)
    assert doc["format"] == FORMAT and doc["tick_rule"] == TICK_RULE
    assert doc["value_labels"] == {"b": ["off", "on"]}
    assert doc["commands"] == {"dimensions": ["throttle"], "units": ["unit"],
                               "values": [[0.0], [1.0]]}
    assert tree_from_dict(BehaviorTree, doc) == bt
    linear = Commands(("throttle",), ("unit",), ((0.0,), (1.0,)), (((( 0, 2.0),),), ((),)))
    doc = tree_to_dict(_bt(commands=linear))
    assert doc["format"] == FORMAT_LINEAR and "terms" in doc["commands"]
    assert tree_from_dict(BehaviorTree, doc) == _bt(commands=linear)
    assert "value_labels" not in tree_to_dict(_bt()) and "commands" not in tree_to_dict(_bt())


def test_node_to_dict_writes_every_kind():
    assert node_to_dict(Inverter(Action(1))) == {"type": "inverter", "children": [
        {"type": "action", "action": 1}]}
    assert node_to_dict(Fallback((Action(0),))) == {"type": "fallback", "children": [
        {"type": "action", "action": 0}]}
    assert node_to_dict(Condition(1, "<=", 2))["threshold"] == 2.0


# -------------------------------------------------------------------------------- reading
def test_a_document_without_format_or_rule_is_format_1():
    doc = _doc()
    del doc["format"], doc["tick_rule"]
    assert tree_from_dict(BehaviorTree, doc) == _bt()


@pytest.mark.parametrize("doc, words", [
    ([1], "a behavior-tree document is a JSON object, got list"),
    ({"feature_names": ["a"]}, "behavior-tree JSON lacks the key 'action_names'; expected "
     "feature_names, action_names and root"),
    ({"action_names": ["a"], "root": {}}, "lacks the key 'feature_names'"),
    ({"feature_names": ["a"], "action_names": ["a"]}, "lacks the key 'root'"),
])
def test_a_document_that_is_no_object_or_lacks_a_key_is_refused(doc, words):
    _refused(doc, words)


def test_unknown_keys_formats_and_rules_are_refused():
    _refused(_doc(zeta=1, alpha=2), "unknown key 'alpha' in a behavior-tree document; expected "
             "action_names, commands, feature_names, format, root, tick_rule, value_labels")
    _refused(_doc(format="ibt-behavior-tree/3"), "format 'ibt-behavior-tree/3' is not one this "
             "version reads (ibt-behavior-tree/1 or ibt-behavior-tree/2)")
    _refused(_doc(tick_rule="inverted"), "its tick_rule is not the rule this version ticks by")
    _refused(_doc(tick_rule=TICK_RULE + LINEAR_TICK_RULE), "its tick_rule is not")
    assert tree_from_dict(BehaviorTree, _doc(tick_rule=TICK_RULE + RELATIONAL_TICK_RULE)
                          ) == _bt()


def test_value_labels_are_checked():
    _refused(_doc(value_labels=["off"]), "value_labels must map feature names to lists of "
             "labels")
    _refused(_doc(value_labels={"c": ["off"]}), "value_labels names the feature 'c', which is "
             "not in feature_names")
    _refused(_doc(value_labels={"b": "off"}), "value_labels['b']")
    got = tree_from_dict(BehaviorTree, _doc(value_labels={"b": ["off", "on"], "a": ["no"]}))
    assert got.value_labels == ((1, ("off", "on")), (0, ("no",)))


def test_the_tree_read_is_validated():
    _refused(_doc(root={"type": "action", "action": 5}), "action 5, but the tree names 2 "
             "actions")


# ------------------------------------------------------------------------------- the nodes
@pytest.mark.parametrize("node, words", [
    ("x", "root: a node is a JSON object, got str"),
    ({"type": "loop"}, "root: unknown node type 'loop'; expected one of selector, sequence, "
     "fallback, inverter, condition, action"),
    ({"type": 3}, "root: unknown node type 3;"),
    ({"type": "action"}, "root: a action node lacks 'action'; its keys are action, type"),
    ({"type": "action", "action": 0, "zz": 1, "aa": 2},
     "root: a action node has the unknown key 'aa'; its keys are action, type"),
    ({"type": "condition", "feature": 0, "op": "<=", "threshold": 0.5, "form": {}},
     "root: a condition has either 'feature' (a test of one feature) or 'form' (a relational "
     "test), not both"),
    ({"type": "condition", "form": {"features": [0, 1], "weights": [1, 1]}, "op": "<="},
     "root: a condition node lacks 'threshold'; its keys are form, op, threshold, type"),
    ({"type": "condition", "form": [0], "op": "<=", "threshold": 0.5},
     "root: a linear form must be"),
    ({"type": "condition", "feature": 0, "op": "==", "threshold": 0.5}, "root: "),
    ({"type": "action", "action": -1}, "root: "),
    ({"type": "selector", "children": {}}, "root: children must be a list of nodes"),
    ({"type": "selector", "children": []}, "root: a selector needs at least one child"),
    ({"type": "inverter", "children": []}, "root: an inverter has exactly one child, got 0"),
    ({"type": "inverter", "children": [{"type": "action", "action": 0}] * 2},
     "root: an inverter has exactly one child, got 2"),
    ({"type": "sequence", "children": [{"type": "action", "action": 0}, 7]},
     "root.children[1]: a node is a JSON object, got int"),
    ({"type": "fallback", "children": [{"type": "inverter", "children": [{"type": "x"}]}]},
     "root.children[0].children[0]: unknown node type 'x'"),
])
def test_a_bad_node_is_refused_saying_where(node, words):
    with pytest.raises(ValueError) as err:
        node_from_dict(node)
    assert str(err.value).startswith(words), str(err.value)


def test_every_node_kind_reads_as_written():
    for node in (Condition(1, "<=", 0.5), Action(1), Inverter(Action(0)), Fallback((Action(0),)),
                 Sequence((Condition(0, ">", 0.0), Action(1))), ROOT,
                 Condition.relational(LinearForm(1, 0, 2.0, 3.0), ">", -1.0),
                 Condition.relational(ObliqueForm((0, 1, 2), (1.0, 2.0, 3.0)), "<=", 0.0)):
        assert node_from_dict(node_to_dict(node)) == node


def _chain(levels: int) -> dict:
    node: dict = {"type": "action", "action": 0}
    for _ in range(levels):
        node = {"type": "inverter", "children": [node]}
    return node


def test_a_document_may_be_max_depth_deep_and_no_deeper():
    node_from_dict(_chain(MAX_DEPTH))
    with pytest.raises(ValueError) as err:
        node_from_dict(_chain(MAX_DEPTH + 1))
    assert str(err.value) == (f"root: the behavior tree is more than {MAX_DEPTH} levels deep; "
                              "a BT this deep is not one ibt writes")


def test_the_document_reads_through_the_strict_reader():
    text = json.dumps(tree_to_dict(_bt()))
    assert BehaviorTree.from_json(text) == _bt()
    with pytest.raises(ValueError, match="duplicate key 'root'"):
        BehaviorTree.from_json(text[:-1] + ', "root": {"type": "action", "action": 0}}')
