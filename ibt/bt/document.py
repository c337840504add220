"""The JSON document of a Behavior Tree (``ibt-behavior-tree/1``, the format of ``data/trees/``):
a tree written as plain data, and read back strictly.

Reading is strict so that a file decides as it reads: UTF-8 JSON without duplicate keys
(:func:`strict_json`), every key known, every node checked with an error that says where
(``root.children[2]``), and the tick rule the document was written for equal to the one this
version ticks by. The nodes and the tree are :mod:`ibt.bt.model`'s, whose
``BehaviorTree.to_dict`` / ``from_dict`` / ``from_json`` call :func:`tree_to_dict`,
:func:`tree_from_dict` and :func:`strict_json` (importing this module when first called, as this
module imports the model); files are read and written by :mod:`ibt.bt.json_io`.
"""

from __future__ import annotations

import json
from typing import Any

from ibt.bt.linear import MAX_TERMS, ObliqueForm, form_from_json
from ibt.bt.model import (
    MAX_DEPTH,
    NODE_TYPES,
    Action,
    BehaviorTree,
    Commands,
    Condition,
    Fallback,
    Inverter,
    Node,
    Selector,
    Sequence,
    checked_names,
)

FORMAT = "ibt-behavior-tree/1"
#: the format of a BT with linear commands or oblique tests (1, 3 or 4 terms); every other BT is
#: written as before, so its file and digest do not change
FORMAT_LINEAR = "ibt-behavior-tree/2"
FORMATS = (FORMAT, FORMAT_LINEAR)
TICK_RULE = ("condition succeeds iff float64(float32(obs[feature])) op threshold; an action "
             "succeeds and is the decision; selector/fallback succeed at the first success; "
             "sequence fails at the first failure; inverter flips")
# appended only for a BT with relational conditions (axis-aligned documents stay as they were)
RELATIONAL_TICK_RULE = ("; a condition with a form {features: [i, j], weights: [w1, w2]} "
                        "succeeds iff (w1 * x[i]) + (w2 * x[j]) op threshold, computed in "
                        "float64 left to right with x = float64(float32(obs))")
# the rule of a format-2 document: forms of any number of terms, and linear commands
LINEAR_TICK_RULE = (f"; a condition with a form {{features: [f1, ..., fk], weights: [w1, ..., wk]}}"
                    f" (k <= {MAX_TERMS}) succeeds iff w1 * x[f1] + ... + wk * x[fk] op "
                    "threshold, summed in float64 left to right with x = float64(float32(obs)); "
                    "dimension d of a command with terms sends values[d] + w1 * x[f1] + ... + "
                    "wk * x[fk], summed in float64 left to right, which the environment clips "
                    "to its action space")
DOCUMENT_KEYS = frozenset({"format", "feature_names", "action_names", "tick_rule",
                           "value_labels", "commands", "root"})


def no_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``'s ``object_pairs_hook`` that refuses a key given twice (JSON keeps the
    last silently: a file would not read as it looks)."""
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise ValueError(f"duplicate key {key!r:.60}")
        doc[key] = value
    return doc


def strict_json(text: str | bytes) -> Any:
    """The JSON value of ``text``; ``ValueError`` if it is not UTF-8, not JSON, has a duplicate
    key or is nested too deeply for the parser (NaN literals are read: the reader of the value
    says which field must be finite)."""
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        return json.loads(text, object_pairs_hook=no_duplicate_keys)
    except RecursionError:
        raise ValueError("nested too deeply to be a behavior tree") from None
    except ValueError as err:  # JSONDecodeError, UnicodeDecodeError, duplicate keys
        raise ValueError(f"not strict JSON ({' '.join(str(err).split())})") from None

def tree_to_dict(bt: BehaviorTree) -> dict[str, Any]:
    """The JSON document of ``data/trees/`` of ``bt`` (:meth:`BehaviorTree.to_dict`; read back
    by :func:`tree_from_dict`)."""
    extra = ({"value_labels": {bt.feature_names[f]: list(v) for f, v in bt.value_labels}}
             if bt.value_labels else {})
    linear = needs_linear_format(bt)
    rule = (LINEAR_TICK_RULE if linear else RELATIONAL_TICK_RULE if bt.relational_count else "")
    return {
        "format": FORMAT_LINEAR if linear else FORMAT,
        "feature_names": list(bt.feature_names),
        "action_names": list(bt.action_names),
        "tick_rule": TICK_RULE + rule,
        **extra,
        **({"commands": bt.commands.to_dict()} if bt.commands is not None else {}),
        "root": node_to_dict(bt.root),
    }


def tree_from_dict(cls: type[BehaviorTree], doc: Any) -> BehaviorTree:
    """Read a document of :func:`tree_to_dict` as a ``cls``, strictly
    (:meth:`BehaviorTree.from_dict`): ``ValueError`` names the first problem (missing or unknown
    keys, a fractional index, a non-finite threshold, an index out of range, a state that
    reaches no action; see :meth:`BehaviorTree.validate`)."""
    if not isinstance(doc, dict):
        raise ValueError(f"a behavior-tree document is a JSON object, got "
                         f"{type(doc).__name__}")
    missing = [key for key in ("feature_names", "action_names", "root") if key not in doc]
    if missing:
        raise ValueError(f"behavior-tree JSON lacks the key {missing[0]!r:.60}; expected "
                         "feature_names, action_names and root")
    unknown = sorted(set(doc) - DOCUMENT_KEYS)
    if unknown:
        raise ValueError(f"unknown key {unknown[0]!r:.60} in a behavior-tree document; "
                         f"expected {', '.join(sorted(DOCUMENT_KEYS))}")
    written = doc.get("format", FORMAT)
    if written not in FORMATS:
        raise ValueError(f"format {written!r:.60} is not one this version reads "
                         f"({' or '.join(FORMATS)})")
    rules = ((TICK_RULE + LINEAR_TICK_RULE,) if written == FORMAT_LINEAR
             else (TICK_RULE, TICK_RULE + RELATIONAL_TICK_RULE))
    if doc.get("tick_rule", rules[0]) not in rules:
        raise ValueError("its tick_rule is not the rule this version ticks by (a BT "
                         "written for other semantics would not decide as its author meant);"
                         " remove the key or write the BT with this version")
    names = checked_names(doc["feature_names"], "feature_names")
    labels_doc = doc.get("value_labels", {})
    if not isinstance(labels_doc, dict):
        raise ValueError("value_labels must map feature names to lists of labels")
    labels = []
    for feature, values in labels_doc.items():
        if feature not in names:
            raise ValueError(f"value_labels names the feature {feature!r:.60}, which is not in "
                             "feature_names")
        labels.append((names.index(feature),
                       checked_names(values, f"value_labels[{feature!r:.60}]")))
    action_names = checked_names(doc["action_names"], "action_names")
    commands = (Commands.from_dict(doc["commands"], len(action_names))
                if "commands" in doc else None)
    tree = cls(root=node_from_dict(doc["root"]), feature_names=names,
               action_names=action_names, value_labels=tuple(labels), commands=commands)
    if written == FORMAT and needs_linear_format(tree):
        raise ValueError(f"a BT with linear commands or tests of 1, 3 or 4 features is format "
                         f"{FORMAT_LINEAR!r}; write that format")
    tree.validate()
    return tree


def needs_linear_format(bt: BehaviorTree) -> bool:
    """Does ``bt`` use what format 2 added (linear commands, oblique forms)?"""
    return (bt.commands is not None and bt.commands.linear) or any(
        isinstance(node, Condition) and isinstance(node.form, ObliqueForm) for node in bt.nodes())

def node_to_dict(node: Node) -> dict[str, Any]:
    if isinstance(node, Condition) and node.form is not None:
        return {"type": "condition", "form": node.form.to_json(), "op": node.op,
                "threshold": float(node.threshold)}
    if isinstance(node, Condition):
        return {"type": "condition", "feature": node.feature, "op": node.op,
                "threshold": float(node.threshold)}
    if isinstance(node, Action):
        return {"type": "action", "action": node.action}
    return {"type": node.type, "children": [node_to_dict(c) for c in node.children]}


_NODE_KEYS = {"condition": {"type", "feature", "op", "threshold"}, "action": {"type", "action"},
              **{kind: {"type", "children"}
                 for kind in ("selector", "fallback", "sequence", "inverter")}}
_RELATIONAL_KEYS = {"type", "form", "op", "threshold"}
_COMPOSITES: dict[str, type[Selector | Fallback | Sequence]] = {
    "selector": Selector, "fallback": Fallback, "sequence": Sequence}

def node_from_dict(doc: Any, where: str = "root", depth: int = 0) -> Node:
    """One node of the JSON format, strictly; errors say where (``root.children[2]``).

    Deeper than :data:`MAX_DEPTH` levels is a ``ValueError`` (not a RecursionError)."""
    if depth > MAX_DEPTH:
        raise ValueError(f"{where.split('.children')[0]}: the behavior tree is more than "
                         f"{MAX_DEPTH} levels deep; a BT this deep is not one ibt writes")
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: a node is a JSON object, got {type(doc).__name__}")
    kind = doc.get("type")
    if not isinstance(kind, str) or kind not in _NODE_KEYS:
        raise ValueError(f"{where}: unknown node type {kind!r:.60}; expected one of "
                         f"{', '.join(NODE_TYPES)}")
    keys = _NODE_KEYS[kind]
    if kind == "condition" and "form" in doc:
        if "feature" in doc:
            raise ValueError(f"{where}: a condition has either 'feature' (a test of one feature)"
                             " or 'form' (a relational test), not both")
        keys = _RELATIONAL_KEYS
    if set(doc) != keys:
        problem = (f"lacks {sorted(keys - set(doc))[0]!r:.60}" if keys - set(doc)
                   else f"has the unknown key {sorted(set(doc) - keys)[0]!r:.60}")
        raise ValueError(f"{where}: a {kind} node {problem}; its keys are "
                         f"{', '.join(sorted(keys))}")
    try:
        if kind == "condition" and "form" in doc:
            return Condition.relational(form_from_json(doc["form"]), doc["op"],
                                        doc["threshold"])
        if kind == "condition":
            return Condition(doc["feature"], doc["op"], doc["threshold"])
        if kind == "action":
            return Action(doc["action"])
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    if not isinstance(doc["children"], list):
        raise ValueError(f"{where}: children must be a list of nodes")
    children = tuple(node_from_dict(c, f"{where}.children[{i}]", depth + 1)
                     for i, c in enumerate(doc["children"]))
    if kind == "inverter":
        if len(children) != 1:
            raise ValueError(f"{where}: an inverter has exactly one child, got {len(children)}")
        return Inverter(children[0])
    if not children:
        raise ValueError(f"{where}: a {kind} needs at least one child")
    return _COMPOSITES[kind](children)
