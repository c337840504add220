"""The registry of BT synthesisers: what an entry is by default, how a name is looked up, which
entries make the front, and how an entry dispatches a plain and a relational tree."""

from __future__ import annotations

from dataclasses import FrozenInstanceError
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.synth import registry
from ibt.synth.registry import (
    SYNTHESISERS,
    Synthesiser,
    front_synthesisers,
    get_synthesiser,
    register_synthesiser,
)

BASELINES = ("bt-espresso", "re-bt-espresso")
FRONT = ("imitation-bt", "decision-list")  # the paper's construction and its decision list


def _calls(tree, task, **options):
    """A stand-in synthesiser: returns what it was called with."""
    return ("called", tree, task, options)


def test_an_entry_defaults_to_an_off_front_imitation_bt_source_without_a_version():
    entry = Synthesiser("x", "tests.test_synth_registry:_calls")
    assert entry.source == "imitation-bt" and entry.on_front is False
    assert entry.version is None and entry.version_number() is None
    assert entry.description == ""


def test_an_entry_is_a_frozen_value():
    """An entry is shared by the CLI, the grid and worker processes: nobody may edit it in
    place (``register_synthesiser`` replaces it), and equal entries are one key."""
    entry = Synthesiser("x", "tests.test_synth_registry:_calls")
    with pytest.raises(FrozenInstanceError):
        entry.on_front = True  # type: ignore[misc]
    assert {entry, Synthesiser("x", "tests.test_synth_registry:_calls")} == {entry}


def test_the_built_in_entries_name_their_functions_sources_and_front():
    for name in (*FRONT, *BASELINES):
        entry = get_synthesiser(name)
        assert entry.name == name and callable(entry.resolve(entry.function))
    assert all(get_synthesiser(n).on_front and get_synthesiser(n).source == "imitation-bt"
               for n in FRONT)
    assert all(not get_synthesiser(n).on_front and get_synthesiser(n).source == "baseline"
               for n in BASELINES)
    assert get_synthesiser("imitation-bt").function == "ibt.synth.imitation:imitation_bt"
    assert front_synthesisers() == FRONT  # in registry order


def test_a_version_is_resolved_from_its_module():
    from ibt.synth import decision_list

    assert get_synthesiser("decision-list").version_number() == decision_list.VERSION
    assert get_synthesiser("imitation-bt").version_number() is None


@given(st.text(min_size=1, max_size=12))
def test_a_registered_entry_is_found_by_name_and_replaces_an_older_one(name):
    entries = dict(SYNTHESISERS)
    try:
        first = register_synthesiser(Synthesiser(name, "tests.test_synth_registry:_calls"))
        assert get_synthesiser(name) is first
        second = Synthesiser(name, "tests.test_synth_registry:_calls", on_front=True)
        assert register_synthesiser(second) is second and get_synthesiser(name) is second
        assert list(SYNTHESISERS).count(name) == 1 and name in front_synthesisers()
    finally:
        SYNTHESISERS.clear()
        SYNTHESISERS.update(entries)


def test_an_unknown_name_is_refused_with_the_known_ones():
    with pytest.raises(ValueError, match="unknown BT method 'no-such'") as raised:
        get_synthesiser("no-such")
    assert all(name in str(raised.value) for name in SYNTHESISERS)
    assert raised.value.__cause__ is None and raised.value.__suppress_context__


def test_only_on_front_entries_make_the_front(monkeypatch):
    monkeypatch.setattr(registry, "SYNTHESISERS", {})
    register_synthesiser(Synthesiser("b", "m:f", on_front=True))
    register_synthesiser(Synthesiser("a", "m:f"))
    register_synthesiser(Synthesiser("c", "m:f", on_front=True))
    assert front_synthesisers() == ("b", "c")


def test_a_plain_tree_goes_to_the_function_with_its_options():
    entry = Synthesiser("x", "tests.test_synth_registry:_calls")
    tree, task = SimpleNamespace(), object()
    assert entry(tree, task, check=False) == ("called", tree, task, {"check": False})
    tree.feature_map_ = None  # an unfitted relational tree is still a plain one
    assert entry(tree, task)[0] == "called"


def test_a_relational_tree_goes_through_the_relational_route(monkeypatch):
    from ibt.synth import relational

    seen = []
    monkeypatch.setattr(relational, "synthesise",
                        lambda function, tree, task, **o: seen.append((function, tree, task, o))
                        or "relational")
    entry = Synthesiser("x", "tests.test_synth_registry:_calls")
    tree, task = SimpleNamespace(feature_map_=object()), object()
    assert entry(tree, task, check=True) == "relational"
    assert seen == [(_calls, tree, task, {"check": True})]
