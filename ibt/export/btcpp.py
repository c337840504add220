"""Export a :class:`ibt.bt.model.BehaviorTree` to BehaviorTree.CPP v4 XML (and read it back).

Two flavours, both read back by :func:`from_btcpp_xml`:

* ``portable`` (the default) runs in stock BehaviorTree.CPP 4.x: the user registers only the
  actions. A condition is the engine's built-in ``ScriptCondition`` over a blackboard entry named
  after the feature, ``<ScriptCondition code="velocity &gt; 0.0023324477951973677"
  name="velocity > 0.002332"/>``: ``code`` is exact (the threshold is ``repr`` of the double, so it
  round-trips), ``name`` is a readable label (``carrying == heavy`` for categorical features).
  Before each tick the caller sets every blackboard key (:func:`blackboard_keys`) to
  ``double(float(obs[i]))``, the float32-rounded observation as a double: that is this package's
  tick rule, so the engine then decides exactly as :meth:`BehaviorTree.decide`.
* ``check-feature`` keeps the conditions as one custom node type,
  ``<Condition ID="CheckFeature" feature="2" op="<=" threshold="0.05"/>``, which the user must
  implement in C++ (Python-registered nodes cannot declare its ports).

In both, ``Selector`` and ``Fallback`` -> ``<Fallback>`` (a Selector, the root of a synthesised
policy, carries ``name="Selector"`` so that reading back restores it), ``Sequence`` ->
``<Sequence>``, ``Inverter`` -> ``<Inverter>``, and each action is its own port-less node type,
``<Action ID="push_right"/>``, declared in the ``<TreeNodesModel>`` that Groot2 reads. The file
names no ``main_tree_to_execute`` (Groot2 drops it on save); it holds one tree, which the engine
runs. An XML comment at the top lists the blackboard keys.

Names become identifiers deterministically: every character other than ASCII letters, digits and
``_`` becomes ``_``; a feature key that does not start with a letter, or starts with ``true`` or
``false`` (BehaviorTree.CPP's script parser reads those as the boolean literals and fails), gets
the prefix ``f_``; an action ID that starts with a digit gets a leading ``_``, and one that names
a built-in node gets its index appended; a name that collides with an earlier one gets
``_<index>`` appended (feature or action index) until unique.

Categorical features keep their exact threshold comparison in ``code`` (``carrying &gt; 1.5``):
the engine's script enums must be registered in C++ (``registerScriptingEnum``; behaviortreepy
0.1.4 does not expose it), and the XML must load with only the actions registered. The readable
form is the ``name``. ``ElementTree`` escapes ``<`` and ``>`` in attribute values.
"""

from __future__ import annotations

import math
import re
import sys
import xml.etree.ElementTree as ET
from collections.abc import Sequence as Seq

import numpy as np

from ibt.bt.linear import LinearForm, linear_form, script_sum
from ibt.bt.model import (
    Action,
    BehaviorTree,
    Commands,
    Condition,
    Fallback,
    Inverter,
    Node,
    Selector,
    Sequence,
)

FLAVOURS = ("portable", "check-feature")
CONDITION_ID = "CheckFeature"
SCRIPT_CONDITION = "ScriptCondition"
SELECTOR_NAME = "Selector"
_PORTS = (
    ("feature", "int", "index of the feature in the observation vector"),
    ("op", "std::string", "comparison: <= or >"),
    ("threshold", "double", "succeed iff double(float(obs[feature])) op threshold"),
)
# node IDs BehaviorTree.CPP 4 registers itself (checked with behaviortreepy 0.1.4: registering
# an action under any of them fails), and the XML's own tag names
BUILTIN_IDS = frozenset("""
    AlwaysFailure AlwaysSuccess AsyncFallback AsyncSequence Delay Fallback ForceFailure
    ForceSuccess IfThenElse Inverter KeepRunningUntilFailure LoopBool LoopDouble LoopInt
    LoopString Parallel ParallelAll Precondition ReactiveFallback ReactiveSequence Repeat
    RetryUntilSuccessful RunOnce Script ScriptCondition Sequence SequenceWithMemory
    SetBlackboard SkipUnlessUpdated Sleep SubTree Switch2 Switch3 Switch4 Switch5 Switch6
    Timeout UnsetBlackboard WaitValueUpdate WasEntryUpdated WhileDoElse
    Action Condition Control Decorator BehaviorTree TreeNodesModel root
    """.split()) | {CONDITION_ID}
_CODE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(<=|>)\s*(\S+)\s*$")
_KEY = r"([A-Za-z_][A-Za-z0-9_]*)"
_TERM = re.compile(rf"^\s*(\S+)\s*\*\s*{_KEY}\s*$")
_OBLIQUE_CODE = re.compile(r"^\s*(.+?)\s+(<=|>)\s+(\S+)\s*$")
_FORM_CODE = re.compile(rf"^\s*(\S+)\s*\*\s*{_KEY}\s*\+\s*(\S+)\s*\*\s*{_KEY}\s*(<=|>)\s*(\S+)\s*$")
#: the same, both sides scaled (a subnormal threshold): ``(w1 * a + w2 * b) * SCALE op T``
_SCALED_FORM_CODE = re.compile(rf"^\s*\(\s*(\S+)\s*\*\s*{_KEY}\s*\+\s*(\S+)\s*\*\s*{_KEY}\s*\)"
                               rf"\s*\*\s*(\S+)\s*(<=|>)\s*(\S+)\s*$")
_XML_DECLARATION = '<?xml version="1.0" encoding="UTF-8"?>\n'


# what XML 1.0 allows in text and attributes (its production Char); the rest is replaced
_NOT_XML_CHAR = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")
REPLACEMENT = "\ufffd"


def xml_safe(text: str) -> str:
    """``text`` with every character XML 1.0 cannot hold (control characters, lone
    surrogates, U+FFFE/U+FFFF) replaced by U+FFFD: any Unicode name becomes well-formed XML
    once escaped (ElementTree escapes ``&``, ``<``, ``>`` and quotes in attributes)."""
    return _NOT_XML_CHAR.sub(REPLACEMENT, text)


def comment_safe(text: str) -> str:
    """``text`` fit for an XML comment: :func:`xml_safe`, no ``--`` anywhere (every run of
    hyphens is split by spaces) and no trailing hyphen, so that no name can close the comment."""
    text = xml_safe(text)
    while "--" in text:
        text = text.replace("--", "- -")
    return text + " " if text.endswith("-") else text


def _identifier(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", name)


def _unique(ident: str, index: int, taken: list[str]) -> str:
    while ident in taken:
        ident = f"{ident}_{index}"
    return ident


def blackboard_keys(feature_names: Seq[str]) -> list[str]:
    """The blackboard key of each feature: a script identifier, unique, close to the name."""
    keys: list[str] = []
    for index, name in enumerate(feature_names):
        key = _identifier(name)
        if not key[:1].isalpha() or key.startswith(("true", "false")):
            key = "f_" + key
        keys.append(_unique(key, index, keys))
    return keys


def action_ids(action_names: Seq[str]) -> list[str]:
    """BehaviorTree.CPP node IDs for the actions: identifiers, unique, no built-in node's ID."""
    ids: list[str] = []
    for index, name in enumerate(action_names):
        ident = _identifier(name) or "action"
        if ident[0].isdigit():
            ident = "_" + ident
        if ident in BUILTIN_IDS:
            ident = f"{ident}_{index}"
        ids.append(_unique(ident, index, ids))
    return ids


#: a relational condition's two sides are multiplied by this where its threshold is subnormal:
#: every subnormal double times 2**300 is normal, and no sum of two weighted float32 features
#: overflows (its magnitude stays far below 2**724)
SUBNORMAL_SCALE = 2.0**300


def _subnormal(number: float) -> bool:
    """A nonzero double below the smallest normal one, which ``std::stod`` rejects."""
    return number != 0.0 and abs(number) < sys.float_info.min


def threshold_text(threshold: float) -> str:
    """The threshold as the engine parses it back to the same double (``repr``).

    ``std::stod`` rejects subnormal doubles, so one of those becomes the largest float32 value
    at or below it: ``x op t`` and ``x op that`` agree for every float32 ``x`` (a relational
    condition, whose left side is a double, is scaled instead: :func:`condition_code`).
    """
    t = float(threshold)
    if not math.isfinite(t):
        raise ValueError(f"threshold {t} is not finite; BehaviorTree.CPP scripts need a number")
    if _subnormal(t):
        below = np.float32(t)
        if float(below) > t:
            below = np.nextafter(below, np.float32(-np.inf))
        t = float(below)
    return repr(t)


COMMAND_KEY = "command"  #: the blackboard key a command's Script writes its id to


def command_keys(bt: BehaviorTree) -> list[str]:
    """The output keys of a BT with commands: the command id's key, then one per dimension
    (identifiers, unique, none a feature's key)."""
    assert bt.commands is not None
    taken = blackboard_keys(bt.feature_names)
    keys: list[str] = []
    for index, name in enumerate((COMMAND_KEY, *bt.commands.dimensions)):
        key = _identifier(name)
        if not key[:1].isalpha() or key.startswith(("true", "false")):
            key = "c_" + key
        key = _unique(key, index, taken + keys)
        keys.append(key)
    return keys


def command_code(bt: BehaviorTree, action: int, keys: Seq[str]) -> str:
    """The ``Script`` code of a command: ``command := 2; main_engine := 0.8; ...``; a linear
    command's dimension is ``main_engine := -1.0 + 10.0 * y + -10.0 * vy`` (numbers by
    ``repr``: the engine sums left to right in double, the floating-point rule of
    :mod:`ibt.bt.linear`, so it sends exactly what ``ibt`` sends)."""
    assert bt.commands is not None
    values = bt.commands.values[action]
    terms = (bt.commands.terms[action] if bt.commands.terms is not None
             else ((),) * len(values))
    feature_keys = blackboard_keys(bt.feature_names)
    return "; ".join([f"{keys[0]} := {action}",
                      *(f"{key} := " + script_sum([threshold_text(v), *(
                          f"{w!r} * {feature_keys[f]}" for f, w in dim_terms)])
                        for key, v, dim_terms in zip(keys[1:], values, terms, strict=True))])


def condition_code(node: Condition, keys: Seq[str]) -> str:
    """The ``ScriptCondition`` code of a condition: ``velocity > 0.0023324477951973677``; a
    relational one is ``1.0 * x + -1.0 * vx <= 0.5`` (weights and threshold by ``repr``: the
    engine computes ``(w1 * x) + (w2 * vx)`` in double, the floating-point rule of
    :mod:`ibt.bt.linear`, so it decides exactly as ``ibt``)."""
    if node.form is not None:
        for _, weight in node.form.terms:
            if abs(weight) < sys.float_info.min:
                raise ValueError(f"weight {weight!r} of {node.form} is subnormal, which "
                                 "BehaviorTree.CPP's number parser rejects; use a larger one")
        t = float(node.threshold)
        if _subnormal(t):  # the sum is a double (no float32 snap): scale both sides by a
            # power of two, which is exact
            return (f"({node.form.script(keys)}) * {SUBNORMAL_SCALE!r} {node.op} "
                    f"{threshold_text(t * SUBNORMAL_SCALE)}")
        return f"{node.form.script(keys)} {node.op} {threshold_text(t)}"
    return f"{keys[node.feature]} {node.op} {threshold_text(node.threshold)}"


def _element(node: Node, bt: BehaviorTree, ids: list[str], keys: list[str],
             flavour: str) -> ET.Element:
    if isinstance(node, Condition):
        if flavour == "portable":
            return ET.Element(SCRIPT_CONDITION, {"code": condition_code(node, keys),
                                                 "name": xml_safe(bt.label(node))})
        return ET.Element("Condition", {
            "ID": CONDITION_ID, "name": xml_safe(bt.label(node)), "feature": str(node.feature),
            "op": node.op, "threshold": threshold_text(node.threshold)})
    if isinstance(node, Action):
        if bt.commands is not None:  # the engine's own Script node writes the command
            return ET.Element("Script", {"code": command_code(bt, node.action, command_keys(bt)),
                                         "name": xml_safe(bt.action_names[node.action])})
        return ET.Element("Action", {"ID": ids[node.action]})
    attrib: dict[str, str] = {}
    if isinstance(node, Inverter):
        tag = "Inverter"
    elif isinstance(node, Sequence):
        tag = "Sequence"
    elif isinstance(node, Selector):
        tag, attrib = "Fallback", {"name": SELECTOR_NAME}
    else:
        tag = "Fallback"
    element = ET.Element(tag, attrib)
    element.extend(_element(child, bt, ids, keys, flavour) for child in node.children)
    return element


def _keys_comment(bt: BehaviorTree, keys: list[str]) -> str:
    lines = [f"    {key} = double(float(obs[{i}]))  ({name})"
             for i, (key, name) in enumerate(zip(keys, bt.feature_names, strict=True))]
    if bt.commands is not None:
        out = command_keys(bt)
        units = [f" ({u})" if u else "" for u in bt.commands.units]
        text = ("\n  Blackboard keys: set each before a tick, as the float32 observation widened "
                "to double.\n" + "\n".join(lines) + "\n  Outputs, written by the command's "
                "Script node on every tick: " + f"{out[0]} (the command's id), "
                + ", ".join(f"{k}{u}" for k, u in zip(out[1:], units, strict=True))
                + "\n  Commands: " + "; ".join(
                    f"{i} = {name}" for i, name in enumerate(bt.action_names)) + "\n  ")
        return comment_safe(text)
    text = ("\n  Blackboard keys: set each before a tick, as the float32 observation widened "
            "to double.\n" + "\n".join(lines) + "\n  Actions: " + ", ".join(
                f"{ident} = {i}" for i, ident in enumerate(action_ids(bt.action_names))) + "\n  ")
    return comment_safe(text)  # no name may close the comment or break the XML


def to_btcpp_xml(bt: BehaviorTree, tree_id: str = "MainTree", flavour: str = "portable") -> str:
    """The BehaviorTree.CPP v4 XML of ``bt`` (pretty printed), with its node model."""
    if flavour not in FLAVOURS:
        raise ValueError(f"unknown BehaviorTree.CPP flavour {flavour!r}; expected one of "
                         f"{FLAVOURS}")
    ids = action_ids(bt.action_names)
    keys = blackboard_keys(bt.feature_names)
    for node in bt.nodes():  # checked here: ElementTree masks errors raised while building
        if isinstance(node, Condition) and node.form is not None:
            if flavour != "portable":
                raise ValueError("a relational condition has no CheckFeature form; export "
                                 "this BT with flavour='portable' (a ScriptCondition)")
            condition_code(node, keys)
    root = ET.Element("root", {"BTCPP_format": "4"})
    if flavour == "portable":
        root.append(ET.Comment(_keys_comment(bt, keys)))
    tree = ET.SubElement(root, "BehaviorTree", {"ID": xml_safe(tree_id)})
    tree.append(_element(bt.root, bt, ids, keys, flavour))
    model = ET.SubElement(root, "TreeNodesModel")
    if flavour == "check-feature":
        condition = ET.SubElement(model, "Condition", {"ID": CONDITION_ID})
        for name, kind, description in _PORTS:
            port = ET.SubElement(condition, "input_port", {"name": name, "type": kind})
            port.text = description
    for ident in ids if bt.commands is None else ():  # commands: only built-in nodes
        ET.SubElement(model, "Action", {"ID": ident})
    ET.indent(root, space="  ")
    return _XML_DECLARATION + ET.tostring(root, encoding="unicode") + "\n"


# ------------------------------------------------------------------------------- reading
DIFFERS = "this file differs from what ibt writes"
#: the attributes each element ibt writes may carry; any other (BehaviorTree.CPP's ``_skipIf``,
#: ``_while``, ``_onSuccess``, ``_post`` ...) changes what the engine runs, which ibt does not
#: model, so a file holding one is refused
ATTRIBUTES = {"root": {"BTCPP_format", "main_tree_to_execute"}, "BehaviorTree": {"ID"},
              SCRIPT_CONDITION: {"code", "name"}, "Script": {"code", "name"},
              CONDITION_ID: {"name", "feature", "op", "threshold"},
              "Inverter": {"name"}, "Sequence": {"name"}, "Fallback": {"name"}}
ACTION_ATTRIBUTES = {"name"}  # <Action ID="go" name="go"/>, or Groot2's compact <go/>


def _check_attributes(element: ET.Element, allowed: set[str]) -> None:
    """``ValueError`` naming the attributes of ``element`` that ibt does not write."""
    extra = sorted(set(element.attrib) - allowed)
    if extra:
        raise ValueError(f"<{element.tag}> has the attribute{'s' * (len(extra) > 1)} "
                         f"{', '.join(extra)}, which ibt does not model ({DIFFERS}: it writes "
                         f"only {', '.join(sorted(allowed)) or 'none'} there)")


def check_layout(root: ET.Element) -> None:
    """The document's top level is what ibt writes: ``<root>`` holding ``<BehaviorTree>`` and
    ``<TreeNodesModel>`` only (no ``<include>``, no other element)."""
    if root.tag != "root":
        raise ValueError(f"the document element is <{root.tag}>, not <root> ({DIFFERS})")
    _check_attributes(root, ATTRIBUTES["root"])
    for child in root:
        if child.tag == "BehaviorTree":
            _check_attributes(child, ATTRIBUTES["BehaviorTree"])
        elif child.tag != "TreeNodesModel":
            raise ValueError(f"<root> holds <{child.tag}>, which ibt does not model ({DIFFERS}:"
                             " it writes only <BehaviorTree> and <TreeNodesModel> there)")


def _form_condition(match: re.Match[str], code: str, feature_of: dict[str, int]) -> Condition:
    """``W1 * KEY1 + W2 * KEY2 OP NUMBER`` back to a relational condition."""
    scaled = match.re is _SCALED_FORM_CODE
    if scaled:
        w1, k1, w2, k2, scale, op, number = match.groups()
        if scale != repr(SUBNORMAL_SCALE):
            raise ValueError(f"ScriptCondition {code!r}: a scaled relational test must be "
                             f"scaled by {SUBNORMAL_SCALE!r} (2**300), as to_btcpp_xml writes")
    else:
        w1, k1, w2, k2, op, number = match.groups()
    for key in (k1, k2):
        if key not in feature_of:
            raise ValueError(f"a ScriptCondition reads the blackboard key {key!r}, which is none "
                             f"of this task's features (keys: {', '.join(feature_of)}); is the "
                             "XML from another task?")
    try:
        form = LinearForm(feature_of[k1], feature_of[k2], float(w1), float(w2))
        threshold = float(number) / SUBNORMAL_SCALE if scaled else float(number)  # exact
        return Condition.relational(form, op, threshold)
    except ValueError as err:
        raise ValueError(f"ScriptCondition {code!r}: {err}") from None


def sum_terms(text: str, code: str, feature_of: dict[str, int], node: str = "Script"
              ) -> tuple[float | None, tuple[tuple[int, float], ...]]:
    """``[BIAS +] W1 * KEY1 + W2 * KEY2 ...`` as to_btcpp_xml writes a sum: its bias (None if
    it has none) and its terms."""
    bias: float | None = None
    terms = []
    for k, part in enumerate(text.replace("(", "").replace(")", "").split(" + ")):
        match = _TERM.match(part)
        try:
            if match is None and k == 0:
                bias = float(part)
                continue
            if match is None:
                raise ValueError
            weight, key = float(match.group(1)), match.group(2)
        except ValueError:
            raise ValueError(f"unsupported {node} code {code!r}: {part!r:.60} is not "
                             "'WEIGHT * KEY' as to_btcpp_xml writes") from None
        if key not in feature_of:
            raise ValueError(f"{node} code {code!r} reads the blackboard key {key!r}, which is "
                             f"none of this task's features (keys: {', '.join(feature_of)})")
        terms.append((feature_of[key], weight))
    return bias, tuple(terms)


def _script_condition(code: str, feature_of: dict[str, int]) -> Condition:
    form = _FORM_CODE.match(code) or _SCALED_FORM_CODE.match(code)
    if form:
        return _form_condition(form, code, feature_of)
    oblique = None if _CODE.match(code) else _OBLIQUE_CODE.match(code)
    if oblique:
        _, terms = sum_terms(oblique.group(1), code, feature_of, SCRIPT_CONDITION)
        try:
            return Condition.relational(linear_form(terms), oblique.group(2),
                                        float(oblique.group(3)))
        except ValueError as err:
            raise ValueError(f"ScriptCondition {code!r}: {err}") from None
    match = _CODE.match(code)
    if not match:
        raise ValueError(f"unsupported ScriptCondition code {code!r}; expected "
                         "'KEY <= NUMBER' or 'KEY > NUMBER' as to_btcpp_xml writes")
    key, op, number = match.groups()
    if key not in feature_of:
        raise ValueError(f"a ScriptCondition reads the blackboard key {key!r}, which is none of "
                         f"this task's features (keys: {', '.join(feature_of)}); is the XML "
                         "from another task?")
    try:
        threshold = float(number)
    except ValueError:
        raise ValueError(f"ScriptCondition {code!r}: {number!r} is not a number") from None
    return Condition(feature_of[key], op, threshold)


def _script_command(code: str, commands: tuple[list[str], Commands, dict[str, int]]) -> Node:
    """A command's ``Script`` back to its action: the id and every value must match."""
    keys, table, feature_of = commands
    parts = [p.split(":=") for p in code.split(";")]
    assigned = {p[0].strip(): p[1].strip() for p in parts if len(p) == 2}
    try:
        action = int(assigned[keys[0]])
        sums = [sum_terms(assigned[k], code, feature_of) for k in keys[1:]]
        values = tuple(float(bias) for bias, _ in sums)  # type: ignore[arg-type]
    except (KeyError, ValueError, TypeError):
        raise ValueError(f"unsupported Script code {code!r}; expected "
                         f"'{keys[0]} := ID; {keys[1]} := VALUE; ...' as to_btcpp_xml writes"
                         ) from None
    terms = tuple(t for _, t in sums)
    wanted = ((table.terms[action] if table.terms is not None else ((),) * len(values))
              if 0 <= action < len(table.values) else None)
    if wanted is None or table.values[action] != values or wanted != terms:
        raise ValueError(f"Script {code!r} writes a command that is not command {action} of "
                         "the BT's command table")
    return Action(action)


def _node(element: ET.Element, action_of: dict[str, int], feature_of: dict[str, int],
          commands: tuple[list[str], Commands, dict[str, int]] | None = None) -> Node:
    tag = element.tag
    ident = element.get("ID", "") if tag in ("Action", "Condition") else tag
    known = ATTRIBUTES.get(ident, ACTION_ATTRIBUTES if ident in action_of else None)
    if known is not None:  # an unknown node is refused below, by its name
        _check_attributes(element, known | ({"ID"} if tag in ("Action", "Condition") else set()))
    if ident == SCRIPT_CONDITION:
        return _script_condition(element.get("code", ""), feature_of)
    if ident == "Script" and commands is not None:
        return _script_command(element.get("code", ""), commands)
    if ident == CONDITION_ID:
        return Condition(int(element.attrib["feature"]), element.attrib["op"],
                         float(element.attrib["threshold"]))
    if tag == "Condition":
        raise ValueError(f"unknown condition node {ident!r}; expected {SCRIPT_CONDITION!r} or "
                         f"{CONDITION_ID!r}")
    if ident in action_of:  # <Action ID="go"/>, or Groot2's compact <go/>
        return Action(action_of[ident])
    if tag == "Action":
        raise ValueError(f"unknown action ID {ident!r}; this task's actions are "
                         f"{', '.join(action_of)}")
    children = [_node(child, action_of, feature_of, commands) for child in element]
    if tag == "Inverter":
        if len(children) != 1:
            raise ValueError(f"an Inverter has exactly one child, got {len(children)}")
        return Inverter(children[0])
    if tag == "Sequence":
        return Sequence(tuple(children))
    if tag == "Fallback":
        cls = Selector if element.get("name") == SELECTOR_NAME else Fallback
        return cls(tuple(children))
    raise ValueError(f"unsupported BehaviorTree.CPP node <{tag}>, which ibt does not model "
                     f"({DIFFERS}: it writes Fallback, Sequence, Inverter, {SCRIPT_CONDITION}, "
                     f"{CONDITION_ID}, Script or an action of this task: "
                     f"{', '.join(action_of)})")


def from_btcpp_xml(text: str, feature_names: Seq[str], action_names: Seq[str],
                   tree_id: str | None = None,
                   value_labels: tuple[tuple[int, tuple[str, ...]], ...] = (),
                   commands: Commands | None = None) -> BehaviorTree:
    """Read XML written by :func:`to_btcpp_xml` (either flavour) back into a BehaviorTree.

    ``tree_id`` defaults to the file's ``main_tree_to_execute``, else its only tree. Raises
    ``ValueError`` naming the problem for XML of another task (an unknown blackboard key or
    action ID) or nodes this package does not write. ``value_labels`` (the task's, or the
    original tree's) only make the read tree's labels readable again. ``commands``: the BT's
    command table (continuous actions), whose ``Script`` nodes are read back as its actions.
    """
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise ValueError(f"not well-formed XML ({err})") from None
    check_layout(root)
    wanted = tree_id or root.get("main_tree_to_execute")
    trees = [t for t in root.findall("BehaviorTree") if wanted is None or t.get("ID") == wanted]
    if not trees:
        raise ValueError(f"no <BehaviorTree ID={wanted!r}> in the XML" if wanted else
                         "no <BehaviorTree> in the XML")
    if len(trees) > 1:
        raise ValueError(f"the XML holds {len(trees)} trees "
                         f"({', '.join(str(t.get('ID')) for t in trees)}); pass tree_id")
    if len(trees[0]) != 1:
        raise ValueError(f"a <BehaviorTree> has exactly one root node, got {len(trees[0])}")
    action_of = {ident: i for i, ident in enumerate(action_ids(action_names))}
    feature_of = {key: i for i, key in enumerate(blackboard_keys(feature_names))}
    shell = BehaviorTree(Action(0), tuple(feature_names), tuple(action_names), (), commands)
    scripts = (command_keys(shell), commands, feature_of) if commands is not None else None
    bt = BehaviorTree(_node(trees[0][0], action_of, feature_of, scripts),
                      tuple(feature_names), tuple(action_names), tuple(value_labels), commands)
    bt.validate()
    return bt
