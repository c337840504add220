"""Export a :class:`ibt.bt.BehaviorTree` to BehaviorTree.CPP v4 XML (and read it back).

The XML runs in BehaviorTree.CPP 4.x (and opens in Groot2) once the node types it declares in
its ``<TreeNodesModel>`` are registered:

* ``Selector`` and ``Fallback`` -> ``<Fallback>`` (a Selector, the root of a synthesised policy,
  carries ``name="Selector"`` so that reading the file back restores it), ``Sequence`` ->
  ``<Sequence>``, ``Inverter`` -> ``<Inverter>``;
* a condition is one custom node type, ``<Condition ID="CheckFeature" name="pole_angle <= 0.05"
  feature="2" op="<=" threshold="0.05"/>``: the ports ``feature`` (index into the observation),
  ``op`` (``<=`` or ``>``) and ``threshold`` (``repr`` of the double, so it round-trips exactly)
  say everything the node needs; ``name`` is a readable label only. The C++ side must compare as
  this package does: ``double(float(obs[feature])) op threshold``;
* each action is its own port-less node type, ``<Action ID="push_right"/>``, as BehaviorTree.CPP
  users register one class per action. The ID is the action name, with characters that are not
  letters, digits or ``_`` replaced by ``_`` (and a leading ``_`` before a digit); collisions get
  the action index appended.

``ElementTree`` escapes ``<`` and ``>`` in attribute values, so ``op="&lt;="`` in the file.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence as Seq

from ibt.bt import Action, BehaviorTree, Condition, Fallback, Inverter, Node, Selector, Sequence

CONDITION_ID = "CheckFeature"
SELECTOR_NAME = "Selector"
_PORTS = (
    ("feature", "int", "index of the feature in the observation vector"),
    ("op", "std::string", "comparison: <= or >"),
    ("threshold", "double", "succeed iff double(float(obs[feature])) op threshold"),
)


def action_ids(action_names: Seq[str]) -> list[str]:
    """BehaviorTree.CPP node IDs for the actions: identifiers, unique, close to the names."""
    ids: list[str] = []
    for index, name in enumerate(action_names):
        ident = re.sub(r"\W", "_", name, flags=re.ASCII) or "action"
        if ident[0].isdigit():
            ident = "_" + ident
        if ident in ids or ident == CONDITION_ID:
            ident = f"{ident}_{index}"
        ids.append(ident)
    return ids


def _element(node: Node, bt: BehaviorTree, ids: list[str]) -> ET.Element:
    if isinstance(node, Condition):
        return ET.Element("Condition", {
            "ID": CONDITION_ID, "name": bt.label(node), "feature": str(node.feature),
            "op": node.op, "threshold": repr(float(node.threshold))})
    if isinstance(node, Action):
        return ET.Element("Action", {"ID": ids[node.action]})
    if isinstance(node, Inverter):
        tag, attrib = "Inverter", {}
    elif isinstance(node, Sequence):
        tag, attrib = "Sequence", {}
    elif isinstance(node, Selector):
        tag, attrib = "Fallback", {"name": SELECTOR_NAME}
    else:
        tag, attrib = "Fallback", {}
    element = ET.Element(tag, attrib)
    element.extend(_element(child, bt, ids) for child in node.children)
    return element


def to_btcpp_xml(bt: BehaviorTree, tree_id: str = "MainTree") -> str:
    """The BehaviorTree.CPP v4 XML of ``bt`` (pretty printed), with its node model."""
    ids = action_ids(bt.action_names)
    root = ET.Element("root", {"BTCPP_format": "4", "main_tree_to_execute": tree_id})
    tree = ET.SubElement(root, "BehaviorTree", {"ID": tree_id})
    tree.append(_element(bt.root, bt, ids))
    model = ET.SubElement(root, "TreeNodesModel")
    condition = ET.SubElement(model, "Condition", {"ID": CONDITION_ID})
    for name, kind, description in _PORTS:
        port = ET.SubElement(condition, "input_port", {"name": name, "type": kind})
        port.text = description
    for ident in ids:
        ET.SubElement(model, "Action", {"ID": ident})
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode", xml_declaration=False) + "\n"


def _node(element: ET.Element, action_of: dict[str, int]) -> Node:
    tag = element.tag
    children = [_node(child, action_of) for child in element]
    if tag == "Condition":
        if element.get("ID") != CONDITION_ID:
            raise ValueError(f"unknown condition node {element.get('ID')!r}; expected "
                             f"{CONDITION_ID!r}")
        return Condition(int(element.attrib["feature"]), element.attrib["op"],
                         float(element.attrib["threshold"]))
    if tag == "Action":
        ident = element.get("ID", "")
        if ident not in action_of:
            raise ValueError(f"unknown action node {ident!r}; expected one of "
                             f"{sorted(action_of)}")
        return Action(action_of[ident])
    if tag == "Inverter":
        if len(children) != 1:
            raise ValueError(f"an Inverter has exactly one child, got {len(children)}")
        return Inverter(children[0])
    if tag == "Sequence":
        return Sequence(tuple(children))
    if tag == "Fallback":
        cls = Selector if element.get("name") == SELECTOR_NAME else Fallback
        return cls(tuple(children))
    raise ValueError(f"unsupported BehaviorTree.CPP node <{tag}>; expected Fallback, Sequence, "
                     "Inverter, Condition or Action")


def from_btcpp_xml(text: str, feature_names: Seq[str], action_names: Seq[str],
                   tree_id: str | None = None) -> BehaviorTree:
    """Read XML written by :func:`to_btcpp_xml` back into a :class:`BehaviorTree`.

    ``tree_id`` defaults to the file's ``main_tree_to_execute``.
    """
    root = ET.fromstring(text)
    wanted = tree_id or root.get("main_tree_to_execute")
    trees = [t for t in root.findall("BehaviorTree") if wanted is None or t.get("ID") == wanted]
    if not trees:
        raise ValueError(f"no <BehaviorTree ID={wanted!r}> in the XML")
    if len(trees[0]) != 1:
        raise ValueError(f"a <BehaviorTree> has exactly one root node, got {len(trees[0])}")
    action_of = {ident: i for i, ident in enumerate(action_ids(action_names))}
    bt = BehaviorTree(_node(trees[0][0], action_of),
                      tuple(feature_names), tuple(action_names))
    bt.validate()
    return bt
