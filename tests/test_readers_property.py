"""Hostile files: any mutation of a valid BT file or decision-tree file is read exactly or refused.

The law, for the BT JSON reader (:func:`ibt.bt.json_io.load_json`) and the tree-file reader
(:func:`ibt.distill.tree_file.load_tree_file`): a mutated file (a byte flipped, a key deleted or
given twice, a value of another type, NaN or infinity, a huge number, the text cut short, a value
nested thousands of levels deep, an array element of a tree changed) is either

* read exactly: the BT read is the document's BT (its nodes are the file's nodes, written back it
  reads equal) and decides on random states; the tree read predicts on random states, as the same
  tree written back and read again, and synthesises a BT or refuses with a ``ValueError``; or
* refused with a ``ValueError`` of one short line, which the command line turns into exit code 2
  (:func:`ibt.cli.main.main` turns ``ValueError`` into one line and exit code 2).

Any other exception type (``TypeError``, ``OverflowError``, ``IndexError``, ``RecursionError``)
fails the test: it would be a traceback. The CLI cases at the end run the commands themselves.
"""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.json_io import load_json, save_json
from ibt.bt.model import BehaviorTree
from ibt.cli import main
from ibt.distill.loop import tree_signature
from ibt.distill.relational import fit_relational_tree
from ibt.distill.tree_codec import from_document
from ibt.distill.tree_file import load_tree_file, save_tree_file
from ibt.synth.imitation import imitation_bt
from ibt.tasks.catalogue import get_task

CARTPOLE = get_task("CartPole-v1")
MAX_MESSAGE = 600  # characters: a refusal names the problem, it does not echo the file
HOSTILE = [None, True, False, 0, -1, 1, 2, 7, 0.5, -0.0, 1e308, -1e308, 10**30, -(10**30),
           10**400, math.nan, math.inf, -math.inf, "", "x", "0.5", [], [1, 2], {}, {"a": 1},
           {"__float__": "nan"}, {"__tuple__": [1]}, {"__numpy__": "<f8", "value": 1.0},
           {"__array__": ["f8", 0, [1000000]]}, {"__array__": ["f8", -5, [2]]},
           {"__numpy__": "O", "value": 1}, {"type": "action", "action": 0}]
DEEP = "@@deep@@"  # replaced in the text by a value nested deeper than any parser's stack
SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (keys and indices) into a JSON value, the root's included."""
    out = [prefix]
    if isinstance(value, dict):
        for key, child in value.items():
            out += _paths(child, (*prefix, key))
    elif isinstance(value, list):
        for i, child in enumerate(value):
            out += _paths(child, (*prefix, i))
    return out


def _at(doc: Any, path: tuple) -> Any:
    for step in path:
        doc = doc[step]
    return doc


@st.composite
def _mutated_text(draw: st.DrawFn, doc: dict) -> bytes:
    """The JSON text of ``doc`` with one mutation, drawn over every place in the document."""
    doc = json.loads(json.dumps(doc))
    kind = draw(st.sampled_from(["replace", "delete", "duplicate", "deep", "flip", "truncate",
                                 "insert"]))
    if kind in ("replace", "delete", "duplicate", "deep"):
        path = draw(st.sampled_from(_paths(doc)[1:]))
        parent, last = _at(doc, path[:-1]), path[-1]
        if kind == "replace":
            parent[last] = draw(st.sampled_from(HOSTILE))
        elif kind == "delete":
            del parent[last]
        elif kind == "deep":
            parent[last] = DEEP
        elif isinstance(parent, dict):  # the same key again, with another value
            text = json.dumps(doc)
            head = json.dumps({last: draw(st.sampled_from(HOSTILE[:8]))})[1:-1]
            where = text.index(json.dumps(last) + ":")
            return (text[:where] + head + ", " + text[where:]).encode()
        else:
            parent.insert(last, parent[last])
        text = json.dumps(doc)
        levels = draw(st.sampled_from([200, 5000, 100_000]))
        return text.replace(json.dumps(DEEP), "[" * levels + "]" * levels).encode()
    raw = json.dumps(doc).encode()
    at = draw(st.integers(0, len(raw) - 1))
    if kind == "truncate":
        return raw[:at]
    if kind == "insert":
        return raw[:at] + draw(st.sampled_from([b"NaN", b"1e999", b"-", b"\x00", b"\\", b'"',
                                                b",", b"9" * 5000, b"\xff", b"\xed\xa0\x80"])
                               ) + raw[at:]
    flipped = bytearray(raw)
    flipped[at] ^= 1 << draw(st.integers(0, 7))
    return bytes(flipped)


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _refused_cleanly(err: ValueError) -> None:
    message = str(err)
    assert message and "\n" not in message and len(message) < MAX_MESSAGE, message


# --------------------------------------------------------------------------------- BT files
def _bt_documents() -> dict[str, dict]:
    rng = np.random.default_rng(0)
    x = CARTPOLE.sample_features(2000, rng)
    y = (x[:, 2] + 0.5 * x[:, 3] > 0).astype(int)
    tree = DecisionTreeClassifier(max_leaf_nodes=5, random_state=0).fit(x, y)
    relational = {
        "format": "ibt-behavior-tree/1", "feature_names": ["where", "speed"],
        "action_names": ["brake", "go"],
        "value_labels": {"where": ["home", "road", "shop"]},
        "commands": {"dimensions": ["force"], "units": ["N"], "values": [[-1.0], [2.5]]},
        "root": {"type": "selector", "children": [
            {"type": "sequence", "children": [
                {"type": "condition", "form": {"features": [0, 1], "weights": [1.0, -0.5]},
                 "op": "<=", "threshold": 0.25},
                {"type": "inverter", "children": [
                    {"type": "condition", "feature": 0, "op": ">", "threshold": 1.5}]},
                {"type": "action", "action": 0}]},
            {"type": "action", "action": 1}]}}
    relational["tick_rule"] = BehaviorTree.from_dict(relational).to_dict()["tick_rule"]
    return {"cartpole": imitation_bt(tree, CARTPOLE).bt.to_dict(), "relational": relational}


BT_DOCS = _bt_documents()


def _bt_read_exactly(bt: BehaviorTree, text: bytes) -> None:
    doc = json.loads(text)
    written = bt.to_dict()
    for key, value in doc.items():
        if key not in ("format", "tick_rule"):
            assert written.get(key, {}) == value, key  # the file's BT, node for node
    assert BehaviorTree.from_json(bt.to_json()) == bt
    states = np.random.default_rng(1).normal(size=(64, bt.n_features)).astype(np.float32)
    assert set(bt.decide(states).tolist()) <= set(range(len(bt.action_names)))


@pytest.mark.parametrize("name", sorted(BT_DOCS))
@SETTINGS
@given(data=st.data())
def test_a_mutated_bt_file_is_read_exactly_or_refused(name, data, tmp_path_factory):
    text = data.draw(_mutated_text(BT_DOCS[name]))
    path = _write(tmp_path_factory.mktemp("bt") / "bt.json", text)
    try:
        bt = load_json(path)
    except ValueError as err:
        _refused_cleanly(err)
        assert str(path) in str(err)
        return
    _bt_read_exactly(bt, text)


def test_the_unmutated_bt_files_are_read():
    for doc in BT_DOCS.values():
        assert BehaviorTree.from_dict(doc).to_dict() == doc


# ------------------------------------------------------------------------------- tree files
@pytest.fixture(scope="module")
def tree_files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("trees")
    rng = np.random.default_rng(0)
    x = CARTPOLE.sample_features(2000, rng)
    y = (x[:, 2] + 0.5 * x[:, 3] > 0).astype(int)
    plain = DecisionTreeClassifier(max_leaf_nodes=5, random_state=0).fit(x, y)
    relational = fit_relational_tree(x, y, max_leaf_nodes=4)
    assert relational.n_relational >= 1
    save_tree_file(folder / "plain.json", plain, CARTPOLE, {"algo": "ppo", "seed": 0})
    save_tree_file(folder / "relational.json", relational, CARTPOLE, {"algo": "dqn"})
    return {"plain": folder / "plain.json", "relational": folder / "relational.json"}


def _pools(doc: dict) -> dict[str, np.ndarray]:
    return {name: np.frombuffer(base64.b64decode(text), dtype=f"<{name}").copy()
            for name, text in doc["tree"]["arrays"].items()}


@st.composite
def _mutated_tree_text(draw: st.DrawFn, doc: dict) -> bytes:
    """A mutation of the JSON (as for BTs) or of one element of the tree's arrays."""
    if draw(st.booleans()):
        return draw(_mutated_text(doc))
    doc = json.loads(json.dumps(doc))
    pools = _pools(doc)
    name = draw(st.sampled_from(sorted(pools)))
    array = pools[name]
    at = draw(st.integers(0, len(array) - 1))
    if name.startswith("f"):
        array[at] = draw(st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0,
                                          -2.0, 5e-324, array[at] * 2]))
    else:
        value = draw(st.sampled_from([0, 1, -1, -2, 2, 3, 7, 2**31 - 1, -(2**31), 2**63 - 1]))
        array.view(f"u{array.itemsize}")[at] = value % (1 << 8 * array.itemsize)  # wraps
    doc["tree"]["arrays"][name] = base64.b64encode(array.tobytes()).decode("ascii")
    return json.dumps(doc).encode()


def _decides(tree: Any, n: int = 64) -> np.ndarray:
    states = CARTPOLE.sample_features(n, np.random.default_rng(2))
    return np.asarray(tree.predict(states))


@pytest.mark.parametrize("name", ["plain", "relational"])
@SETTINGS
@given(data=st.data())
def test_a_mutated_tree_file_is_read_exactly_or_refused(name, data, tree_files,
                                                        tmp_path_factory):
    doc = json.loads(tree_files[name].read_text())
    text = data.draw(_mutated_tree_text(doc))
    folder = tmp_path_factory.mktemp("tree")
    path = _write(folder / "tree.json", text)
    try:
        read = load_tree_file(path)
    except ValueError as err:
        _refused_cleanly(err)
        assert str(path) in str(err)
        return
    tree = read["tree"]
    decisions = _decides(tree)
    assert set(decisions.tolist()) <= set(range(len(read["action_names"])))
    again = save_tree_file(folder / "again.json", tree, CARTPOLE,
                           {k: v for k, v in read.items()
                            if k not in ("tree", "task", "gym_id", "feature_names",
                                         "action_names", "format", "format_version")})
    reread = load_tree_file(again)["tree"]
    assert tree_signature(reread) == tree_signature(tree)
    assert np.array_equal(_decides(reread), decisions)
    try:  # what `synthesize` does next: a BT, or a one-line refusal
        bt = imitation_bt(tree, CARTPOLE).bt
    except ValueError as err:
        _refused_cleanly(err)
        return
    states = CARTPOLE.sample_features(64, np.random.default_rng(2))
    assert np.array_equal(bt.decide(states), decisions)


# ---------------------------------------------------------------- the commands themselves
def _set_threshold(doc: dict, value: float, node: int = 0) -> dict:
    doc = json.loads(json.dumps(doc))
    pools = _pools(doc)
    tree = doc["tree"]["value"]
    tree = tree.get("__sklearn_tree__") or tree["__sklearn_relational_tree__"]
    fields = tree["tree_"]["__sklearn_Tree__"]["state"]["nodes"]["fields"]
    pool, offset, _ = fields["threshold"]["__array__"]
    pools[pool][offset + node] = value
    doc["tree"]["arrays"][pool] = base64.b64encode(pools[pool].tobytes()).decode("ascii")
    return doc


@pytest.mark.parametrize("command", [["evaluate", "{f}", "--episodes", "1"],
                                     ["synthesize", "{f}", "-o", "{o}/bt.json"],
                                     ["refine", "{f}", "-o", "{o}/small.json"]])
@pytest.mark.parametrize(("name", "value", "node"), [("plain", math.nan, 0),
                                                      ("plain", math.inf, 2),
                                                      ("relational", -math.inf, 0)])
def test_every_command_refuses_a_non_finite_threshold_naming_file_and_node(
        command, name, value, node, tree_files, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    doc = _set_threshold(json.loads(tree_files[name].read_text()), value, node)
    bad.write_text(json.dumps(doc))
    out = tmp_path / "out"
    out.mkdir()
    argv = [a.replace("{f}", str(bad)).replace("{o}", str(out)) for a in command]
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1, captured.err
    assert str(bad) in captured.err and f"node {node} has the threshold" in captured.err
    assert list(out.iterdir()) == []


@pytest.mark.parametrize(("text", "words"), [
    ('"threshold": 10' + "0" * 400, "threshold must be finite"),
    ('"threshold": 1' + "0" * 30, "threshold must be finite"),  # no double is exactly 10**30
    ('"threshold": 1e999', "threshold must be finite"),
    ('"threshold": NaN', "threshold must be finite"),
    ('"op": "<=", "op": ">"', "duplicate key 'op'"),
])
def test_the_bt_commands_refuse_hostile_numbers_and_keys(text, words, tmp_path, capsys):
    doc = BT_DOCS["cartpole"]
    good = json.dumps(doc)
    first = good.index('"op": ')
    if text.startswith('"op"'):
        bad_text = good[:first] + text + good[first + len('"op": "<="'):]
    else:
        start = good.index('"threshold": ')
        end = min(good.index(c, start) for c in ",}" if c in good[start:])
        bad_text = good[:start] + text + good[end:]
    bad = tmp_path / "bt.json"
    bad.write_text(bad_text)
    for argv in (["evaluate", str(bad), "--task", "CartPole-v1", "--episodes", "1"],
                 ["export", str(bad), "--format", "dot", "-o", str(tmp_path / "bt.dot")]):
        assert main(argv) == 2
        captured = capsys.readouterr()
        assert len(captured.err.splitlines()) == 1 and words in captured.err, captured.err
    with pytest.raises(ValueError, match=words):
        load_json(bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bt.json"]


def test_a_saved_bt_reads_back_through_the_strict_reader(tmp_path):
    bt = BehaviorTree.from_dict(BT_DOCS["relational"])
    assert load_json(save_json(bt, tmp_path / "bt.json")) == bt


# ------------------------------------------------ the hostile cases, one by one (docs table)
def _estimator(doc: dict) -> dict:
    value = doc["tree"]["value"]
    return value.get("__sklearn_tree__") or value["__sklearn_relational_tree__"]


def _set_array(doc: dict, field: str, at: int, value: float) -> None:
    """Element ``at`` of a node field (or of ``values``, flattened) of the tree's arrays."""
    state = _estimator(doc)["tree_"]["__sklearn_Tree__"]["state"]
    ref = state["values"] if field == "values" else state["nodes"]["fields"][field]
    pool, offset, _ = ref["__array__"]
    pools = _pools(doc)
    pools[pool][offset + at] = value
    doc["tree"]["arrays"][pool] = base64.b64encode(pools[pool].tobytes()).decode("ascii")


def _first_leaf(doc: dict) -> int:
    tree = from_document(doc["tree"])
    return int(np.flatnonzero(tree.tree_.children_left == -1)[0])


def _form(doc: dict) -> dict:
    return _estimator(doc)["feature_map_"]["forms"][0]


#: hostile tree files: (case, base file, how to spoil its JSON document, words of the refusal)
HOSTILE_TREES = [
    ("nan_threshold", "plain", lambda d: _set_array(d, "threshold", 0, math.nan),
     "node 0 has the threshold nan"),
    ("infinite_threshold", "plain", lambda d: _set_array(d, "threshold", 0, -math.inf),
     "node 0 has the threshold -inf"),
    ("threshold_beyond_float32", "plain", lambda d: _set_array(d, "threshold", 0, 1e300),
     "beyond the float32 range"),
    ("nan_impurity", "plain", lambda d: _set_array(d, "impurity", 1, math.nan),
     "node 1 has the impurity nan"),
    ("infinite_sample_weight", "plain",
     lambda d: _set_array(d, "weighted_n_node_samples", 2, math.inf),
     "node 2 has the weighted n node samples inf"),
    ("infinite_class_value", "plain", lambda d: _set_array(d, "values", 6, math.inf),
     "node 3 has a class value that is not finite"),
    ("node_with_two_parents", "plain", lambda d: _set_array(d, "right_child", 0, 1),
     "has two parents"),
    ("leaf_that_tests_a_feature", "plain",
     lambda d: _set_array(d, "feature", _first_leaf(d), 0), "is a leaf but has a feature"),
    ("attribute_shadowing_predict", "plain", lambda d: _estimator(d).__setitem__("predict", 1),
     "unknown attribute 'predict'"),
    ("missing_fitted_attribute", "plain", lambda d: _estimator(d).pop("n_outputs_"),
     "lacks 'n_outputs_'"),
    ("invalid_parameter", "plain", lambda d: _estimator(d).__setitem__("criterion", "x"),
     "'criterion' parameter"),
    ("class_count_disagrees", "plain", lambda d: _estimator(d).__setitem__("n_classes_", 3),
     "n_classes_"),
    ("relational_nan_threshold", "relational", lambda d: _set_array(d, "threshold", 0, math.nan),
     "node 0 has the threshold nan"),
    ("relational_weight_too_large", "relational",
     lambda d: _form(d).__setitem__("weights", [1e308, -1.0]), "are too large"),
    ("relational_infinite_weight_text", "relational",
     lambda d: _form(d).__setitem__("weights", [10**400, -1.0]), "must be finite and non-zero"),
    ("relational_fractional_width", "relational",
     lambda d: _estimator(d)["feature_map_"].__setitem__("n_features", 4.5),
     "n_features must be a non-negative integer"),
]


@pytest.mark.parametrize(("case", "base", "spoil", "words"), HOSTILE_TREES,
                         ids=[case[0] for case in HOSTILE_TREES])
def test_a_hostile_tree_file_is_refused_by_name(case, base, spoil, words, tree_files, tmp_path,
                                                capsys):
    doc = json.loads(tree_files[base].read_text())
    spoil(doc)
    bad = tmp_path / f"{case}.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ValueError) as refused:
        load_tree_file(bad)
    assert words in str(refused.value) and str(bad) in str(refused.value)
    assert main(["synthesize", str(bad), "-o", str(tmp_path / "bt.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and words in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == [bad.name]


def _spoil_bt(change: Any) -> bytes:
    doc = json.loads(json.dumps(BT_DOCS["cartpole"]))
    change(doc)
    return json.dumps(doc).encode()


#: hostile BT files beyond those of tests/test_bad_input.py: (case, file bytes, words)
HOSTILE_BTS = [
    ("other_tick_rule", _spoil_bt(lambda d: d.__setitem__("tick_rule", "x op threshold")),
     "tick_rule is not the rule this version ticks by"),
    ("node_type_a_list", _spoil_bt(lambda d: d["root"].__setitem__("type", ["selector"])),
     "unknown node type"),
    ("key_of_5000_digits", _spoil_bt(lambda d: d.__setitem__("9" * 5000, 1)),
     "unknown key '99999"),
    ("nested_100000_levels", b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    ("truncated", json.dumps(BT_DOCS["cartpole"]).encode()[:-40], "not strict JSON"),
    ("not_utf8", b'{"feature_names": ["\xff"]}', "not strict JSON"),
]


@pytest.mark.parametrize(("case", "data", "words"), HOSTILE_BTS,
                         ids=[case[0] for case in HOSTILE_BTS])
def test_a_hostile_bt_file_is_refused_by_name(case, data, words, tmp_path, capsys):
    bad = tmp_path / f"{case}.json"
    bad.write_bytes(data)
    with pytest.raises(ValueError) as refused:
        load_json(bad)
    message = str(refused.value)
    assert words in message and str(bad) in message and len(message) < MAX_MESSAGE
    assert main(["export", str(bad), "--format", "dot", "-o", str(tmp_path / "bt.dot")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and words in err and len(err) < MAX_MESSAGE, err
    assert sorted(p.name for p in tmp_path.iterdir()) == [bad.name]
