"""A run's plan: the ladder records the steps it took under the clock (names, seeds of each
search's restarts and each polish, where it stopped); replayed, with no deadline and on any
number of cores, the same steps give the same candidates and the same BT; a plan file is data,
checked field by field, and bad input is one line naming the fix."""

from __future__ import annotations

import json
import shutil

import pytest

from ibt.engine.deadline import Deadline
from ibt.engine.keys import tree_key
from ibt.engine.ladder import Settings, run_ladder
from ibt.engine.plan import (
    PlanError,
    PlannedStep,
    PlannedStop,
    Replay,
    check_made_for,
    document,
    dumps,
    made_for,
    read_plan,
    summary,
)
from tests.test_pipeline_engine import _line_agent

SETTINGS = {"keep": 0.95, "budget": "smoke", "leaves": [4], "seed": 0, "restarts": 1,
            "episodes": 5, "max_nodes": None}
FOR = made_for("ToyLine-v0", "ppo", "ab" * 32, SETTINGS)


def _front(ladder):
    return [(c.stage, c.leaf_limit, c.learner, tree_key(c.tree), c.bt_nodes, c.mean_return)
            for c in ladder.candidates]


def test_a_replayed_plan_takes_the_same_steps_and_seeds_on_any_cores_without_a_clock(
        agents, tmp_path):
    """Under a deadline the ladder's last search spends spare time on extra restarts and
    polishes again one seed a core; the plan records them, and its replay on one core and on
    two, with no deadline, runs exactly those restarts and seeds: the same front."""
    import ibt

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    settings = Settings(keep=1.0, rungs=(4,), restarts=1, relational=False, n_jobs=1)
    timed = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                       deadline=Deadline(3600.0))
    steps = [e for e in timed.plan if isinstance(e, PlannedStep)]
    assert [s.name for s in steps] == timed.steps
    assert [s.kind for s in steps][:2] == ["distil", "search"] and steps[-1].kind == "polish"
    searched = next(c for c in timed.candidates if c.stage == "searched")
    assert steps[1].seeds == searched.search.seeds and len(steps[1].seeds) > 1  # spare restarts
    assert steps[0].seeds == (0,) and steps[2].seeds[0] == searched.search.seeds[-1] + 1
    # Expect: the bare ladder (no deadline) would run one restart and no polish; the replay
    # runs the plan's
    bare = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0)
    assert len(bare.steps) == 2 and bare.candidates[1].search.seeds == (0,)
    for jobs in (1, 2):
        again = run_ladder(cfg, agent, Settings(**{**settings.__dict__, "n_jobs": jobs}),
                           agent_mean=0.0, random_mean=-10.0,
                           replay=Replay(timed.plan, "plan.json"))
        assert again.stopped is None and again.plan == timed.plan
        assert _front(again) == _front(timed)


def test_a_replay_stops_where_the_plan_stopped_and_then_polishes_as_it_did(agents, tmp_path):
    """A stop recorded before a step ends the replay's climb there, as it ended the run's; a
    plan whose steps the ladder does not ask for is refused in one line."""
    import ibt

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    settings = Settings(keep=1.0, rungs=(4, 8), restarts=1, relational=False)
    stopped = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                         on_step=lambda done, step: "enough" if done.steps else None)
    assert stopped.plan[-1] == PlannedStop("enough", "distil axis at 8 leaves")
    again = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                       replay=Replay(stopped.plan))
    assert again.steps == stopped.steps and again.plan == stopped.plan
    assert again.stopped is None and _front(again) == _front(stopped)
    other = [PlannedStep("distil axis at 16 leaves", "distil", "distilled", "axis", 16, (0,))]
    with pytest.raises(PlanError, match=r"entry 1 is the step \"distil axis at 16 leaves\" "
                                        r"but this run's ladder asks for \"distil axis at 4"):
        run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                   replay=Replay(other))


def test_the_plan_round_trips_as_json_and_bad_plans_name_the_fix():
    entries = [PlannedStep("distil axis at 4 leaves", "distil", "distilled", "axis", 4, (0,)),
               PlannedStep("search axis at 4 leaves", "search", "searched", "axis", 4, (0, 1)),
               PlannedStop("time", "polish again axis at 4 leaves")]
    text = dumps(document(FOR, entries))
    doc = json.loads(text)
    assert doc["ended"] == "time" and doc["settings"] == SETTINGS
    assert read_plan(text.encode(), "p.json") == (FOR, entries)
    assert summary(entries) == ("1 distil step, a search at 4 leaves (2 restarts); stopped "
                                "(time) at \"polish again axis at 4 leaves\"")
    assert summary(entries[:1]) == "1 distil step; the ladder finished"

    def bad(change, match):
        changed = json.loads(text)
        change(changed)
        with pytest.raises(PlanError, match=match) as err:
            read_plan(json.dumps(changed).encode(), "p.json")
        assert "\n" not in str(err.value)

    bad(lambda d: d.update(format="x"), "not a pipeline plan")
    bad(lambda d: d.update(ibt_version="0.0.1"), "made by ibt 0.0.1.*make a new one")
    bad(lambda d: d.update(extra=1), "expected the fields")
    bad(lambda d: d["entries"][0].update(kind="exec"), "malformed field")
    bad(lambda d: d["entries"][0].update(seeds=["import os"]), "malformed field")
    bad(lambda d: d["entries"][1].update(seeds=[3, 4]), "a search's seeds are its restarts")
    bad(lambda d: d["entries"].append([1]), "must be a step")
    bad(lambda d: d["settings"].update(seed="0"), "malformed")
    with pytest.raises(PlanError, match=r"not strict JSON.*pass the plan\.json"):
        read_plan(b"{\"format\": ", "p.json")
    with pytest.raises(PlanError, match="a plan for ToyLine-v0/ppo, not CartPole-v1/ppo"):
        check_made_for(FOR, {**FOR, "task": "CartPole-v1"}, "p.json")
    with pytest.raises(PlanError, match="another agent"):
        check_made_for(FOR, {**FOR, "agent_sha256": "cd" * 32}, "p.json")
    with pytest.raises(PlanError, match=r"made with --keep 0\.95, this run has 0\.9: pass --keep "
                                        r"0\.95"):
        check_made_for(FOR, {**FOR, "settings": {**SETTINGS, "keep": 0.9}}, "p.json")
    with pytest.raises(PlanError, match=r"this run has 7: drop --max-nodes"):
        check_made_for(FOR, {**FOR, "settings": {**SETTINGS, "max_nodes": 7}}, "p.json")
    check_made_for(FOR, FOR, "p.json")


@pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")
def test_bad_plan_input_exits_2_in_one_line(agents, tmp_path, capsys):
    from ibt.cli import main

    out = tmp_path / "out"
    argv = ["pipeline", "ToyLine-v0", "ppo", "--env-module", "tests.fixtures.toy_line",
            "--checkpoint", str(agents / "line.zip"), "-o", str(out), "--budget", "smoke",
            "--quiet", "--leaves", "4", "--restarts", "1"]
    (tmp_path / "code.json").write_text("__import__('os').system('echo hi')")
    (tmp_path / "other.json").write_text(dumps(document(FOR, [])))
    for plan, said in ((tmp_path / "none.json", "no plan at"),
                       (tmp_path / "code.json", "not strict JSON"),
                       (tmp_path / "other.json", "another agent")):
        assert main([*argv, "--plan", str(plan)]) == 2
        err = capsys.readouterr().err.strip()
        assert said in err and len(err.splitlines()) == 1, err
    assert main([*argv, "--plan", str(plan), "--time", "1m"]) == 2
    assert "--time: not allowed with argument --plan" in capsys.readouterr().err
    assert not out.exists() or not (out / "bt.json").exists()


def _cache_entries(cache):
    return sorted(str(m.parent.relative_to(cache)) for m in cache.glob("*/*/manifest.json"))


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")
def test_a_timed_runs_plan_replayed_on_one_or_two_cores_writes_the_same_bt(agents, tmp_path):
    """End to end, files included: a run under a time limit whose last search spends spare time
    on restarts, then polishes again; its ``plan.json`` read back and replayed from the run's
    cache on one core (no step redone) and from an empty cache on two: ``bt.json`` byte for
    byte, and the same plan. (A target above the agent, 1.01, keeps the search going: the
    command line's ``--keep`` stops at 1.)"""
    from ibt.pipeline.outputs import write_outputs
    from ibt.pipeline.recommend import parse_budget, recommend

    agent = _line_agent(agents)
    run = dict(budget=parse_budget("smoke"), keep=1.01, leaf_limits=(4,), restarts=1,
               progress=False, env_modules=("tests.fixtures.toy_line",))  # for the workers
    first = tmp_path / "first"
    rec = recommend(agent, cache_dir=tmp_path / "c1", time_limit=600.0, n_jobs=1, **run)
    write_outputs(rec, first)
    doc = json.loads((first / "plan.json").read_text())
    kinds = [e.get("kind") for e in doc["entries"]]
    assert kinds[:2] == ["distil", "search"] and "polish" in kinds, kinds
    assert len(doc["entries"][1]["seeds"]) > 1  # the spare time's restarts
    cached = _cache_entries(tmp_path / "c1")
    for folder, jobs, cache in (("one", 1, tmp_path / "c1"), ("two", 2, tmp_path / "c2")):
        planned, entries = read_plan((first / "plan.json").read_bytes(), "plan.json")
        assert planned == {k: doc[k] for k in ("task", "algo", "agent_sha256", "settings")}
        again = recommend(agent, cache_dir=cache, time_limit=1.0, n_jobs=jobs,
                          replay=Replay(entries, "plan.json"), **run)  # no clock: 1 s unused
        write_outputs(again, tmp_path / folder)
        assert (tmp_path / folder / "bt.json").read_bytes() == (first / "bt.json").read_bytes()
        assert (tmp_path / folder / "plan.json").read_bytes() == (first / "plan.json"
                                                                  ).read_bytes()
        assert "This run replayed the plan `plan.json`" in (tmp_path / folder / "report.md"
                                                            ).read_text()
    assert _cache_entries(tmp_path / "c1") == cached  # the replay from it redid no step
