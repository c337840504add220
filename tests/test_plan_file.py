"""A run's plan as data (ibt.engine.plan), without a ladder: a replay hands out the entries in
order and names the first one the ladder does not ask for; the document reads back as written,
one line an entry; a plan made for another task, agent or option is refused naming the option
and its fix; the reader refuses anything but a plan this version wrote, field by field; the
summary counts the steps. Quick: plain data only."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ibt
from ibt.engine import plan
from ibt.engine.plan import (
    PlanError,
    PlannedStep,
    PlannedStop,
    Replay,
    check_made_for,
    describe,
    document,
    dumps,
    made_for,
    read_plan,
    summary,
)

SETTINGS = {"keep": 0.95, "budget": "smoke", "leaves": [4, 8], "seed": 3, "restarts": 2,
            "episodes": 5, "max_nodes": None}
FOR = made_for("ToyLine-v0", "ppo", "ab" * 32, SETTINGS)
DISTIL = PlannedStep("distil axis at 4 leaves", "distil", "distilled", "axis", 4, (3,))
SEARCH = PlannedStep("search axis at 4 leaves", "search", "searched", "axis", 4, (3, 4))
POLISH = PlannedStep("polish axis at 4 leaves", "polish", "polished", "axis", 4, (7, 9))
STOP = PlannedStop("time", "polish again axis at 4 leaves")
BETWEEN = PlannedStop("interrupted", "")


def _text(entries=(DISTIL, SEARCH, STOP)) -> str:
    return dumps(document(FOR, list(entries)))


def _refused(change, match: str) -> PlanError:
    doc = json.loads(_text())
    change(doc)
    with pytest.raises(PlanError, match=match) as raised:
        read_plan(json.dumps(doc).encode(), "p.json")
    assert "\n" not in str(raised.value)
    return raised.value


# -- a replay -----------------------------------------------------------------------------

def test_a_replay_hands_out_the_entries_in_order_then_none():
    replay = Replay([DISTIL, SEARCH, STOP])
    assert replay.peek("distil axis at 4 leaves") is DISTIL
    assert replay.peek("search axis at 4 leaves") is None and replay.done == 0
    assert replay.take("distil axis at 4 leaves") is DISTIL
    assert replay.peek("search axis at 4 leaves") is SEARCH
    assert replay.take("search axis at 4 leaves") is SEARCH
    assert replay.peek("polish again axis at 4 leaves") is None  # a stop is not a step
    assert replay.take("polish again axis at 4 leaves") is STOP
    assert replay.done == 3 and replay.peek("anything") is None
    assert replay.take("anything") is None and replay.done == 3
    replay.check_finished()


def test_a_stop_between_steps_is_taken_whatever_the_ladder_asks_for():
    replay = Replay((BETWEEN,))
    assert replay.take("search axis at 8 leaves") is BETWEEN


def test_a_replay_names_the_entry_the_ladder_does_not_ask_for():
    replay = Replay([DISTIL, SEARCH], source="run/plan.json")
    replay.take("distil axis at 4 leaves")
    with pytest.raises(PlanError) as raised:
        replay.take("refine axis at 4 leaves")
    assert str(raised.value) == (
        "run/plan.json: entry 2 is the step \"search axis at 4 leaves\" but this run's ladder "
        "asks for \"refine axis at 4 leaves\": the plan was made by other code or settings; "
        "make a new one with a run under --time")
    assert replay.done == 1
    with pytest.raises(PlanError, match="entry 1 is a stop \\(time\\) at \"polish again"):
        Replay([STOP]).take("search axis at 4 leaves")


def test_a_replay_that_ends_early_names_what_was_left():
    replay = Replay([DISTIL, SEARCH, STOP])
    replay.take("distil axis at 4 leaves")
    with pytest.raises(PlanError) as raised:
        replay.check_finished()
    assert str(raised.value) == (
        "the plan: the ladder ended with 2 of its entries left (next: the step \"search axis "
        "at 4 leaves\"): the plan was made by other code or settings; make a new one with a "
        "run under --time")
    Replay([]).check_finished()


def test_entries_are_described_in_words():
    assert describe(SEARCH) == "the step \"search axis at 4 leaves\""
    assert describe(STOP) == "a stop (time) at \"polish again axis at 4 leaves\""
    assert describe(BETWEEN) == "a stop (interrupted)"


# -- the document -------------------------------------------------------------------------

def test_a_plan_reads_back_as_written_one_line_an_entry():
    entries = [DISTIL, SEARCH, POLISH, STOP]
    text = _text(entries)
    doc = json.loads(text)
    assert doc["format"] == "ibt-plan" and doc["format_version"] == 1
    assert doc["ibt_version"] == ibt.__version__ and doc["ended"] == "time"
    assert doc["entries"][0] == {"step": "distil axis at 4 leaves", "kind": "distil",
                                 "stage": "distilled", "learner": "axis", "leaves": 4,
                                 "seeds": [3]}
    assert doc["entries"][3] == {"stop": "time", "at": "polish again axis at 4 leaves"}
    assert read_plan(text.encode(), "p.json") == (FOR, entries)
    lines = text.splitlines()
    assert [json.loads(ln.strip().rstrip(",")) for ln in lines
            if ln.startswith("  {")] == doc["entries"]
    assert text.endswith("\n ]\n}\n")


def test_a_plan_without_entries_and_one_that_finished():
    text = _text([])
    assert json.loads(text)["entries"] == [] and json.loads(text)["ended"] == "finished"
    assert text.endswith(',\n "entries": []\n}\n')
    assert read_plan(text.encode(), "p.json") == (FOR, [])
    assert json.loads(_text([DISTIL, STOP, SEARCH]))["ended"] == "finished"  # last is a step


def test_a_plan_holds_no_nan():
    with pytest.raises(ValueError):
        dumps(document(made_for("T", "ppo", "a", {**SETTINGS, "keep": float("nan")}), []))
    with pytest.raises(ValueError):
        dumps({"entries": [{"x": float("inf")}]})


def test_made_for_keeps_only_the_settings_that_change_results():
    got = made_for("T", "dqn", "cd", {**SETTINGS, "jobs": 4, "time": "60m"})
    assert got == {"task": "T", "algo": "dqn", "agent_sha256": "cd", "settings": SETTINGS}
    assert tuple(got["settings"]) == plan.SETTINGS


# -- what a plan was made for ------------------------------------------------------------

def test_a_plan_for_another_task_or_agent_is_refused():
    with pytest.raises(PlanError, match=r"p\.json is a plan for ToyLine-v0/ppo, not "
                                        r"CartPole-v1/ppo: pass the plan"):
        check_made_for(FOR, {**FOR, "task": "CartPole-v1"}, "p.json")
    with pytest.raises(PlanError, match="not ToyLine-v0/dqn"):
        check_made_for(FOR, {**FOR, "algo": "dqn"}, "p.json")
    with pytest.raises(PlanError, match=r"another agent \(SHA-256 abababababab, this one's "
                                        r"cdcdcdcdcdcd\)"):
        check_made_for(FOR, {**FOR, "agent_sha256": "cd" * 32}, "p.json")
    long = {**FOR, "task": "T" * 300, "algo": "a" * 50}
    with pytest.raises(PlanError) as raised:
        check_made_for(long, FOR, "p.json")
    assert f"a plan for {'T' * 100}/{'a' * 20}, not" in str(raised.value)


@pytest.mark.parametrize("name, made, given, said", [
    ("keep", 0.95, 0.9, "made with --keep 0.95, this run has 0.9: pass --keep 0.95"),
    ("max_nodes", None, 7, "made with --max-nodes (none), this run has 7: drop --max-nodes"),
    ("max_nodes", 7, None, "made with --max-nodes 7, this run has (none): pass --max-nodes 7"),
    ("leaves", [4, 8], [4], "made with --leaves 4,8, this run has 4: pass --leaves 4,8"),
    ("seed", 3, 0, "made with --seed 3, this run has 0: pass --seed 3")])
def test_a_plan_made_with_another_option_names_it_and_the_fix(name, made, given, said):
    plan_for = {**FOR, "settings": {**SETTINGS, name: made}}
    run = {**FOR, "settings": {**SETTINGS, name: given}}
    with pytest.raises(PlanError) as raised:
        check_made_for(plan_for, run, "p.json")
    assert str(raised.value) == (f"p.json was made with {said.partition('made with ')[2]} (a "
                                 "replay takes the settings of the run that made the plan) or "
                                 "drop --plan")
    check_made_for(plan_for, plan_for, "p.json")


def test_a_long_setting_is_cut_in_the_message():
    plan_for = {**FOR, "settings": {**SETTINGS, "budget": "b" * 300, "leaves": list(range(99))}}
    with pytest.raises(PlanError) as raised:
        check_made_for(plan_for, FOR, "p.json")
    assert f"--budget {'b' * 100}, this run has smoke" in str(raised.value)
    plan_for = {**FOR, "settings": {**SETTINGS, "leaves": list(range(99))}}
    with pytest.raises(PlanError) as raised:
        check_made_for(plan_for, FOR, "p.json")
    assert f"--leaves {','.join(map(str, range(99)))[:100]}, this" in str(raised.value)


# -- the summary --------------------------------------------------------------------------

def test_the_summary_counts_each_kind_and_names_each_search_and_stop():
    refine = PlannedStep("refine axis at 4 leaves", "refine", "refined", "axis", 4, (3,))
    entries = [DISTIL, refine, refine, SEARCH, POLISH, BETWEEN, STOP]
    assert summary(entries) == (
        "1 distil step, 2 refine steps, a search at 4 leaves (2 restarts), 1 polish step; "
        "stopped (interrupted); stopped (time) at \"polish again axis at 4 leaves\"")
    assert summary([]) == "no step; the ladder finished"
    assert summary([SEARCH, SEARCH]) == ("a search at 4 leaves (2 restarts), a search at 4 "
                                         "leaves (2 restarts); the ladder finished")


# -- reading a plan -----------------------------------------------------------------------

def test_a_file_past_the_size_limit_is_refused_before_it_is_parsed(monkeypatch):
    text = _text().encode()
    monkeypatch.setattr(plan, "MAX_PLAN_BYTES", len(text))
    assert read_plan(text, "p.json")[0] == FOR
    with pytest.raises(PlanError, match="holds more than 0 MiB: no plan is that large"):
        read_plan(text + b" ", "p.json")
    monkeypatch.undo()
    assert plan.MAX_PLAN_BYTES == 4 << 20
    with pytest.raises(PlanError, match="holds more than 4 MiB"):
        read_plan(b" " * ((4 << 20) + 1), "p.json")
    read_plan(_text().encode() + b" " * ((4 << 20) - len(_text().encode())), "p.json")


def test_not_json_or_not_a_plan_is_refused():
    with pytest.raises(PlanError, match=r"p\.json is not a valid plan: not strict JSON .*; "
                                        r"pass the plan\.json a pipeline run wrote"):
        read_plan(b"{\"format\": ", "p.json")
    with pytest.raises(PlanError, match="not a pipeline plan"):
        read_plan(b"[1]", "p.json")
    _refused(lambda d: d.update(format="x"),
             "not a pipeline plan \\(no \"format\": \"ibt-plan\"\\)")


def test_a_plan_of_another_version_is_refused_naming_both():
    err = _refused(lambda d: d.update(ibt_version="0.0.1"), "made by ibt 0.0.1")
    assert f"this is ibt {ibt.__version__} (format 1)" in str(err)
    _refused(lambda d: d.update(format_version=2), r"\(plan format 2\)")
    _refused(lambda d: d.update(ibt_version="9" * 50), f"made by ibt {'9' * 20} \\(")


@pytest.mark.parametrize("change", [
    lambda d: d.update(extra=1), lambda d: d.pop("ended"), lambda d: d.pop("task")])
def test_a_plan_with_other_fields_is_refused(change):
    _refused(change, "expected the fields agent_sha256, algo, ended, entries, format, "
                     "format_version, ibt_version, settings, task, got ")


@pytest.mark.parametrize("change", [
    lambda d: d.update(task=1), lambda d: d.update(algo=None), lambda d: d.update(agent_sha256=[]),
    lambda d: d.update(settings=[]), lambda d: d["settings"].pop("keep"),
    lambda d: d["settings"].update(extra=1), lambda d: d["settings"].update(seed="0"),
    lambda d: d["settings"].update(seed=-1), lambda d: d["settings"].update(seed=True),
    lambda d: d["settings"].update(seed=10**9 + 1), lambda d: d["settings"].update(seed=1.0)])
def test_a_plan_with_malformed_made_for_is_refused(change):
    _refused(change, "its task, algo, agent_sha256 or settings \\(keep, budget, leaves, seed, "
                     "restarts, episodes, max_nodes\\) are missing or malformed")


def test_the_seed_may_be_zero_or_as_large_as_a_billion():
    for seed in (0, 10**9):
        doc = json.loads(_text([]))
        doc["settings"]["seed"] = seed
        assert read_plan(json.dumps(doc).encode(), "p")[0]["settings"]["seed"] == seed


def test_too_many_entries_are_refused(monkeypatch):
    monkeypatch.setattr(plan, "MAX_ENTRIES", 3)
    read_plan(_text([DISTIL, SEARCH, STOP]).encode(), "p.json")
    with pytest.raises(PlanError, match="\"entries\" must be a list of at most 3 steps"):
        read_plan(_text([DISTIL, SEARCH, STOP, STOP]).encode(), "p.json")
    monkeypatch.undo()
    assert plan.MAX_ENTRIES == 10_000
    _refused(lambda d: d.update(entries={}), "must be a list of at most 10,000 steps and stops")


@pytest.mark.parametrize("entry, match", [
    ([1], "entry 1 must be a step \\(fields kind, learner, leaves, seeds, stage, step\\) or a "
          "stop \\(stop, at\\)"),
    ({"stop": "time"}, "must be a step"),
    ({"stop": "time", "at": "", "x": 1}, "must be a step"),
    ({"stop": "", "at": ""}, "entry 1 is a stop whose \"stop\" and \"at\" must be short texts"),
    ({"stop": 1, "at": ""}, "short texts"), ({"stop": "time", "at": None}, "short texts"),
    ({"stop": "t" * 201, "at": ""}, "short texts"), ({"stop": "time", "at": "a" * 201},
                                                     "short texts")])
def test_a_malformed_entry_is_refused(entry, match):
    _refused(lambda d: d["entries"].insert(0, entry), match)


def test_a_stop_of_two_hundred_characters_is_read():
    doc = json.loads(_text([]))
    doc["entries"] = [{"stop": "t" * 200, "at": "a" * 200}]
    assert read_plan(json.dumps(doc).encode(), "p")[1] == [PlannedStop("t" * 200, "a" * 200)]


STEP = {"step": "polish axis at 4 leaves", "kind": "polish", "stage": "polished",
        "learner": "axis", "leaves": 4, "seeds": [7, 9]}


@pytest.mark.parametrize("change", [
    {"kind": "exec"}, {"kind": "distil"}, {"step": "polishing axis"}, {"step": 3},
    {"step": "p" * 201}, {"stage": 1}, {"stage": "s" * 201}, {"learner": None},
    {"learner": "l" * 201}, {"leaves": 0}, {"leaves": True}, {"leaves": "4"}, {"leaves": 4.0},
    {"leaves": 10**9 + 1}, {"seeds": []}, {"seeds": 7}, {"seeds": [-1]}, {"seeds": ["import os"]},
    {"seeds": [False]}, {"seeds": [10**9 + 1]}])
def test_a_malformed_step_is_refused(change):
    _refused(lambda d: d["entries"].insert(0, {**STEP, **change}),
             "entry 1 \\(a step\\) has a malformed field \\(kind one of distil, refine, search, "
             "polish, the step's name starting with it, leaves a positive integer, seeds a list "
             "of integers >= 0\\)")


def test_a_step_at_the_limits_is_read(monkeypatch):
    step = {**STEP, "step": "polish " + "p" * 193, "stage": "s" * 200, "learner": "l" * 200,
            "leaves": 10**9, "seeds": [0, 10**9]}
    doc = json.loads(_text([]))
    doc["entries"] = [step, {**STEP, "leaves": 1}]
    got = read_plan(json.dumps(doc).encode(), "p")[1]
    assert got[0] == PlannedStep(step["step"], "polish", "s" * 200, "l" * 200, 10**9,
                                 (0, 10**9))
    assert got[1].leaves == 1
    monkeypatch.setattr(plan, "MAX_SEEDS", 2)
    read_plan(json.dumps(doc).encode(), "p")
    doc["entries"] = [{**STEP, "seeds": [1, 2, 3]}]
    with pytest.raises(PlanError, match="malformed field"):
        read_plan(json.dumps(doc).encode(), "p")
    monkeypatch.undo()
    assert plan.MAX_SEEDS == 10_000


@pytest.mark.parametrize("seeds", [[4, 5], [3, 5], [0], [2, 3], [3, 4, 6]])
def test_a_search_whose_seeds_are_not_its_restarts_is_refused(seeds):
    err = _refused(lambda d: d["entries"].__setitem__(1, {**d["entries"][1], "seeds": seeds}),
                   "entry 2: a search's seeds are its restarts, the run's seed 3 on; got")
    assert f"got {seeds[:5]};" in str(err)


def test_a_searchs_seeds_are_the_runs_seed_on():
    doc = json.loads(_text())
    doc["entries"][1]["seeds"] = [3, 4, 5, 6, 7, 8]
    assert read_plan(json.dumps(doc).encode(), "p")[1][1].seeds == (3, 4, 5, 6, 7, 8)
    doc["entries"][1]["seeds"] = [3, 4, 5, 6, 7, 9]
    with pytest.raises(PlanError, match=r"got \[3, 4, 5, 6, 7\];"):
        read_plan(json.dumps(doc).encode(), "p")


_step = st.builds(
    lambda kind, leaves, seeds, stage: PlannedStep(f"{kind} axis at {leaves} leaves", kind,
                                                   stage, "axis", leaves, tuple(seeds)),
    st.sampled_from(["distil", "refine", "polish"]), st.integers(1, 10**9),
    st.lists(st.integers(0, 10**9), min_size=1, max_size=4), st.text(max_size=10))
_stop = st.builds(PlannedStop, st.text(min_size=1, max_size=20), st.text(max_size=20))


@settings(max_examples=40, deadline=None)
@given(st.lists(_step | _stop, max_size=6))
def test_every_plan_reads_back_as_written(entries):
    assert read_plan(_text(entries).encode(), "p.json") == (FOR, entries)


def test_the_summary_of_a_plan_read_from_its_file_counts_its_steps():
    """A plan's kinds read from JSON are new strings, not the literals of the code."""
    written = [DISTIL, SEARCH, POLISH, BETWEEN]
    _, entries = read_plan(_text(written).encode(), "p.json")
    assert summary(entries) == summary(written) == (
        "1 distil step, a search at 4 leaves (2 restarts), 1 polish step; stopped "
        "(interrupted)")


def test_a_plan_read_from_its_file_fits_the_run_that_made_it():
    """Its settings read back are equal to the run's, not the same objects."""
    made, _ = read_plan(_text().encode(), "p.json")
    check_made_for(made, FOR, "p.json")
    check_made_for(json.loads(json.dumps(FOR)), FOR, "p.json")
