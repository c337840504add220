"""What a Behavior Tree's model promises beyond deciding: its size limits hold exactly at
:data:`MAX_DEPTH` levels and :data:`MAX_NODES` nodes (one more is refused), its relational
count counts relational conditions only, and its JSON text is the committed format (one
space of indentation) that reads back to the same tree."""

from __future__ import annotations

import json

import numpy as np
import pytest

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
