"""What a Behavior Tree's model promises beyond deciding: its size limits hold exactly at
:data:`MAX_DEPTH` levels and :data:`MAX_NODES` nodes (one more is refused), its relational
count counts relational conditions only, its JSON text is the committed format (one
space of indentation) that reads back to the same tree, a categorical condition's label names
exactly the values on which it holds, and bad thresholds, names and feature indices are refused
naming the problem."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from ibt.bt.linear import LinearForm
from ibt.bt.model import (
    MAX_DEPTH,
    MAX_NODES,
    Action,
    BehaviorTree,
    Condition,
    Inverter,
    Selector,
    Sequence,
    check_size,
    checked_names,
)


def _chain(levels: int):
    """A tree ``levels`` levels below its root: Inverters over one Condition."""
    node = Condition(0, "<=", 0.0)
    for _ in range(levels):
        node = Inverter(node)
    return node


def test_a_tree_may_be_exactly_max_depth_deep_and_no_deeper():
    """Mutants: ``depth > MAX_DEPTH`` as ``==`` or ``>=``, the depth not growing."""
    check_size(_chain(MAX_DEPTH))
    with pytest.raises(ValueError, match=f"more than {MAX_DEPTH} levels deep"):
        check_size(_chain(MAX_DEPTH + 1))


def test_a_tree_may_have_exactly_max_nodes_nodes_and_no_more():
    """Mutants: ``count > MAX_NODES`` as ``==`` or ``>=``."""
    check_size(Selector(tuple(Action(0) for _ in range(MAX_NODES - 1))))
    with pytest.raises(ValueError, match=f"more than {MAX_NODES:,} nodes"):
        check_size(Selector(tuple(Action(0) for _ in range(MAX_NODES))))


def test_the_relational_count_counts_relational_conditions_only():
    """Mutant: ``node.form is not None`` as ``is None`` (the axis-aligned ones counted)."""
    relational = Condition.relational(LinearForm(0, 1), "<=", 0.5)
    root = Selector((Sequence((relational, Condition(0, ">", 1.0), Action(1))),
                     Sequence((Condition(1, "<=", 2.0), Action(0))), Action(2)))
    bt = BehaviorTree(root, ("a", "b"), ("x", "y", "z"))
    assert bt.relational_count == 1
    assert BehaviorTree(Selector((Sequence((Condition(1, "<=", 2.0), Action(0))), Action(2))),
                        ("a", "b"), ("x", "y", "z")).relational_count == 0


def test_the_json_text_is_indented_by_one_space_and_reads_back():
    """Mutant: ``indent=1`` changed (every committed BT file would change)."""
    bt = BehaviorTree(Selector((Sequence((Condition(0, ">", 1.0), Action(1))), Action(0))),
                      ("a",), ("x", "y"))
    text = bt.to_json()
    assert text == json.dumps(bt.to_dict(), indent=1)
    assert text.startswith('{\n "') and "\n  " in text
    assert BehaviorTree.from_json(text) == bt


def test_a_gap_holding_only_infinity_is_named_as_a_state_reaching_no_action():
    """The proof reasons about unbounded regions: the one state a guard ``x <= float32 max``
    leaves out is ``x = inf``, which ticks to no action (decided with non-finite values
    allowed), so the message says that no action is reached there (mutant: that tick refusing
    the non-finite state, which replaces the message with an executor's refusal)."""
    top = float(np.finfo(np.float32).max)
    bt = BehaviorTree(Selector((Sequence((Condition(0, "<=", top), Action(0))),)), ("a",), ("x",))
    with pytest.raises(ValueError, match=r"no action is reached on some states \(e\.g\. a=inf\)"):
        bt.validate()


def test_the_node_limit_is_the_documented_hundred_thousand():
    """The limit is 100,000 nodes, written out (mutant: ``MAX_NODES`` changed, which the test
    above, reading the constant, follows)."""
    check_size(Selector(tuple(Action(0) for _ in range(99_999))))
    with pytest.raises(ValueError, match="more than 100,000 nodes"):
        check_size(Selector(tuple(Action(0) for _ in range(100_000))))


@given(k=st.integers(1, 6), cut=st.integers(-1, 7), op=st.sampled_from(("<=", ">")))
@example(k=3, cut=5, op="<=")
@example(k=3, cut=-1, op=">")
def test_a_categorical_label_names_exactly_the_values_where_the_condition_holds(k, cut, op):
    """``== a``, ``!= a`` or ``in {...}`` over integer codes ``0..k-1``: the set named is the set
    of codes the condition holds on, for thresholds from -0.5 up, the ones a tree learnt on the
    codes has (mutant: ``len(other) == 1`` as ``<= 1``, which reads a label that is not there
    when the condition holds on every code). Below -1 the label is wrong (``c <= -1.5`` over
    two codes reads ``c == v0``: the slice ``labels[:cut + 1]`` counts from the end), a label
    no learnt tree prints; left to the module's owner."""
    labels = tuple(f"v{i}" for i in range(k))
    node = Condition(0, op, cut + 0.5)
    bt = BehaviorTree(Selector((Action(0),)), ("c",), ("x",), value_labels=((0, labels),))
    holds = {labels[v] for v in range(k) if node.holds(np.array([float(v)]))}
    text = bt.label(node)
    if text.startswith("c == "):
        named = {text.removeprefix("c == ")}
    elif text.startswith("c != "):
        named = set(labels) - {text.removeprefix("c != ")}
    else:
        inside = text.removeprefix("c in {").removesuffix("}")
        named = set(inside.split(", ")) if inside else set()
    assert named == holds


def test_a_condition_on_a_feature_the_tree_does_not_name_is_refused():
    """Features are numbered from 0, so one tree of ``n`` features names ``0..n-1`` (mutant:
    ``max(features) < n`` as ``<= n``, which lets feature ``n`` through)."""
    leaf = Sequence((Condition(1, "<=", 0.0), Action(0)))
    bt = BehaviorTree(Selector((leaf, Action(0))), ("a",), ("x",))
    with pytest.raises(ValueError, match="condition on feature 1, but the tree names 1 features"):
        bt.validate()
    BehaviorTree(Selector((leaf, Action(0))), ("a", "b"), ("x",)).validate()


@pytest.mark.parametrize("value", ["1.0", None, True, False, [0.5]])
def test_a_threshold_that_is_not_a_number_is_refused_as_such(value):
    """A string, ``None``, a boolean or a list is not a number, and the message says so
    (mutant: ``isinstance(value, bool) or ...`` as ``and``, which lets them through to the
    finiteness check and its message)."""
    with pytest.raises(ValueError, match="threshold must be a number"):
        Condition(0, "<=", value)
    with pytest.raises(ValueError, match="threshold must be finite"):
        Condition(0, "<=", float("nan"))


@given(st.lists(st.text(min_size=1, max_size=3), min_size=1, max_size=8))
def test_names_are_accepted_exactly_when_distinct(names):
    """A list of non-empty strings is accepted, as a tuple, exactly when no name repeats, and a
    repeated one is named."""
    if len(set(names)) == len(names):
        assert checked_names(names, "names") == tuple(names)
    else:
        with pytest.raises(ValueError, match="twice"):
            checked_names(names, "names")


@pytest.mark.parametrize("n", [256, 257, 1000])
def test_many_distinct_names_are_accepted_and_one_repeat_among_them_refused(n):
    """Hundreds of names (a wide observation) count as well as a few (mutant: the lengths
    compared with ``is not``, which CPython makes differ from ``!=`` above 256, where each
    ``len`` is a new integer object)."""
    names = [f"f{i}" for i in range(n)]
    assert checked_names(names, "feature names") == tuple(names)
    with pytest.raises(ValueError, match="names 'f0' twice"):
        checked_names([*names, "f0"], "feature names")
