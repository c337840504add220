"""Every export survives arbitrary Unicode names: well-formed, one tree, nothing injected.

A feature or action name is data from a file (a BT's JSON, a user's task): it must never close
the BehaviorTree.CPP XML's comment, add an element, break the XML, or become graphviz HTML
(an ``<IMG SRC=...>`` makes ``dot`` read a file).
"""

from __future__ import annotations

import shutil
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pydot
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import Action, BehaviorTree, Condition, Inverter, Selector, Sequence
from ibt.export.btcpp import from_btcpp_xml, to_btcpp_xml
from ibt.export.drawing import decision_tree_graphviz, to_graphviz, trace_graph

# any code point, lone surrogates and control characters included
_chars = st.characters(codec=None, categories=None)
_name = st.text(_chars, min_size=1, max_size=12) | st.sampled_from([
    "z---><include path=\"evil.xml\"/>", "--", "-", "a--b-", "\x00\x01\x1f", "\ud800",
    "<<TABLE><TR><TD><IMG SRC=\"secret.png\"/></TD></TR></TABLE>>", "]]>", "&amp;", "\\N",
    '"quoted"', "\ufffe\uffff"])
_names = st.lists(_name, min_size=2, max_size=3, unique=True)
XML_TAGS = {"root", "BehaviorTree", "Fallback", "Sequence", "Inverter", "ScriptCondition",
            "Condition", "Action", "TreeNodesModel", "input_port"}
HTML_TAGS = {"TABLE", "TR", "TD", "FONT", "HR", "BR", "I", "B"}


def _bt(features: list[str], actions: list[str]) -> BehaviorTree:
    rule = Sequence((Condition(0, "<=", 0.5), Inverter(Condition(1 % len(features), ">", -1.0)),
                     Action(1)))
    return BehaviorTree(Selector((rule, Action(0))), tuple(features), tuple(actions))


def _elements(xml: str, *, comments: bool) -> ET.Element:
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=comments))
    parser.feed(xml.encode("utf-8"))  # UTF-8 must hold it: no lone surrogate
    return parser.close()


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(features=_names, actions=_names, flavour=st.sampled_from(["portable", "check-feature"]))
def test_btcpp_xml_is_well_formed_with_one_tree_and_nothing_injected(features, actions, flavour):
    bt = _bt(features, actions)
    xml = to_btcpp_xml(bt, flavour=flavour)
    root = _elements(xml, comments=True)
    assert root.tag == "root"
    tags = [el.tag for el in root.iter() if isinstance(el.tag, str)]
    assert set(tags) <= XML_TAGS
    assert tags.count("BehaviorTree") == 1  # no <include>, no second tree
    comments = [el for el in root.iter() if el.tag is ET.Comment]
    assert len(comments) == (flavour == "portable")
    # the tree read back decides as the one written: names did not change the structure
    back = from_btcpp_xml(xml, features, actions)
    assert back.root == bt.root


def _html_tags(label: str) -> set[str]:
    body = label[1:-1]  # graphviz HTML label: <...>
    return {el.tag for el in ET.fromstring(f"<X>{body}</X>".encode()).iter()} - {"X"}


def _check_dot(source: str) -> None:
    source.encode("utf-8")
    graphs = pydot.graph_from_dot_data(source)
    assert graphs is not None and len(graphs) == 1
    for node in graphs[0].get_nodes():
        label = node.get_attributes().get("label")
        if label and label.startswith("<"):  # an HTML label: only our table tags
            assert _html_tags(label) <= HTML_TAGS, label


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(features=_names, actions=_names, title=_name)
def test_drawings_escape_every_label(features, actions, title):
    bt = _bt(features, actions)
    _check_dot(to_graphviz(bt, title=title).source)
    _check_dot(to_graphviz(bt, collapse=True).source)
    _check_dot(trace_graph(bt, np.array([0.0, 0.0] + [0.0] * (len(features) - 2)),
                           title=title).source)
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]] * 2)
    tree = DecisionTreeClassifier(random_state=0).fit(x[:, :1].repeat(len(features), 1)[:, :len(
        features)], [0, 1, 0, 1, 0, 1, 0, 1])
    _check_dot(decision_tree_graphviz(tree, features, actions, title=title).source)


@pytest.mark.skipif(shutil.which("dot") is None, reason="graphviz's dot is not installed")
def test_dot_renders_a_hostile_action_name_as_text(tmp_path):
    secret = tmp_path / "secret.png"
    name = f'<<TABLE><TR><TD><IMG SRC="{secret}"/></TD></TR></TABLE>>'
    bt = _bt(["a", "b"], [name, "x\x01--y"])
    svg = subprocess.run(["dot", "-Tsvg"], input=to_graphviz(bt).source.encode(),
                         capture_output=True, check=True).stdout.decode()
    assert "<image" not in svg and "IMG" in svg  # drawn as text, no file read
