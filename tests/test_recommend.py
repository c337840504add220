"""``python -m ibt pipeline``: from a user's own agent to a recommended BT, its files and report.

Two user tasks written in modules (``tests.fixtures.toy_line``: one feature, gymnasium names
only; ``tests.fixtures.toy_cart``: two features, a registered task with readable names), each
with a tiny PPO agent trained here, run under the smoke budget."""

from __future__ import annotations

import json
import shlex
import shutil

import numpy as np
import pytest

from ibt.cli import main
from ibt.engine.agent import sb3_agent
from ibt.pipeline.recommend import Budget, Candidate, choose, held_out, parse_budget

pytestmark = pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")
FILES = ("bt.json", "bt.xml", "bt.png", "bt.svg", "front.png", "plan.json", "report.md")


def _run(argv: list[str]) -> int:
    return main([str(a) for a in argv])


def test_pipeline_writes_its_files_and_a_report_that_reproduces_it(agents, tmp_path, capsys):
    out = tmp_path / "line"
    argv = ["pipeline", "ToyLine-v0", "ppo", "--env-module", "tests.fixtures.toy_line",
            "--checkpoint", agents / "line.zip", "-o", out, "--budget", "smoke", "--quiet"]
    assert _run(argv) == 0
    said = capsys.readouterr().out
    assert "recommended a" in said and "report.md" in said
    assert all((out / name).stat().st_size > 0 for name in FILES)
    report = (out / "report.md").read_text()
    assert ("**Target met**" in report) != ("**Target missed**" in report)
    if "missed" in report.split("\n")[2]:
        assert "Next:" in report
    assert "95 % percentile bootstrap CI over 5 episodes" in report  # intervals named
    assert "otherwise:" in report  # the BT as rules
    # the BT is the one the report's rules describe, and the XML the engine reads is its own
    from ibt.bt.json_io import load_json
    from ibt.export.btcpp import to_btcpp_xml

    bt = load_json(out / "bt.json")
    assert (out / "bt.xml").read_text() == to_btcpp_xml(bt)
    assert f"**{bt.node_count}-node BT**" in report
    # the first command of the report (the run's plan replayed), run from scratch (no cache),
    # writes the same BT; the second (the same run under the clock) the same report
    plan, anytime = report.split("```bash\n")[1].split("\n")[:2]
    assert plan.startswith("python -m ibt pipeline ") and "--plan" in plan
    first = (out / "bt.json").read_bytes()
    shutil.rmtree(out / "cache")
    assert _run(shlex.split(plan, comments=True)[3:]) == 0
    assert (out / "bt.json").read_bytes() == first
    assert _run(shlex.split(anytime, comments=True)[3:]) == 0
    assert (out / "bt.json").read_bytes() == first
    untimed = [line for line in report.splitlines()  # but how long a step took (wall time)
               if not (line.startswith("Note: ") and " took " in line)]
    assert [line for line in (out / "report.md").read_text().splitlines()
            if not (line.startswith("Note: ") and " took " in line)] == untimed


def test_a_two_feature_task_of_a_users_module_reads_its_names(agents, tmp_path):
    from ibt.evaluate.policies import BTPolicy
    from ibt.evaluate.rollouts import retention_norm, rollout
    from ibt.pipeline.recommend import recommend
    from ibt.synth.imitation import verify
    from ibt.tasks.catalogue import resolve_task

    task = resolve_task("ToyCart-v0")
    agent = sb3_agent(task, "ppo", agents / "cart.zip")
    rec = recommend(agent, budget=parse_budget("smoke"), leaf_limits=(8, 4), restarts=1,
                    cache_dir=tmp_path / "cache", progress=False, full=True)
    # every step (full): distillation smallest rung first, axis-aligned, relational, then
    # oblique at the same limit; then the relational search (it covers axis-aligned trees);
    # then refinement
    assert [(c.leaf_limit, c.label) for c in rec.candidates] == [
        (4, "distilled"), (4, "distilled, relational"), (4, "distilled, oblique"),
        (8, "distilled"), (8, "distilled, relational"), (8, "distilled, oblique"),
        (4, "searched, relational"), (8, "searched, relational"),
        (4, "refined"), (4, "refined, relational"), (4, "refined, oblique"),
        (8, "refined"), (8, "refined, relational"), (8, "refined, oblique")]
    assert all(c.leaves <= c.leaf_limit for c in rec.candidates)
    from ibt.engine.learners import learner_of_tree

    for c in rec.candidates:  # every synthesiser's BT decides as its tree
        if learner_of_tree(c.tree) is not None:  # an oblique tree's BT is checked as laid out
            continue
        for bt in c.bts.values():
            verify(bt, c.tree, task)
    # the confirmation numbers are those of fresh episodes, not the choice episodes
    seeds = held_out(rec.episodes, 1)
    assert rec.bt.first_seed == seeds[0] and seeds[0] > held_out(rec.episodes, 0)[-1]
    again = rollout(task, BTPolicy(task, rec.chosen.bt).act, seeds)
    assert np.allclose(again.returns, rec.bt.returns)
    assert rec.retention == pytest.approx(retention_norm(again.mean, rec.agent.mean,
                                                         rec.random.mean))
    from ibt.pipeline.outputs import rules_text, write_outputs

    write_outputs(rec, tmp_path / "cart")
    assert set(FILES) <= {p.name for p in (tmp_path / "cart").iterdir()}
    names = set(task.feature_names) | set(task.action_names)
    assert any(name in rules_text(rec.chosen.bt) for name in names)


def _candidate(nodes: int, retention: float) -> Candidate:
    from ibt.bt.model import Action, BehaviorTree, Selector

    root = Selector(tuple(Action(0) for _ in range(nodes - 1)))
    bt = BehaviorTree(root, ("x",), ("a",))
    return Candidate(4, "distilled", None, {"imitation-bt": bt}, 0.0, 0.0, retention)


def test_the_smallest_bt_that_keeps_the_target_is_chosen_else_the_best():
    small, mid, big = _candidate(3, 90.0), _candidate(6, 96.0), _candidate(9, 99.0)
    assert choose([big, small, mid], 0.95) == (mid, True)
    assert choose([big, small, mid], 0.999) == (big, False)
    tie = _candidate(6, 97.0)
    assert choose([mid, tie], 0.95)[0] is tie  # same size: the higher retention


def test_budget_forms():
    assert parse_budget("smoke").smoke
    assert parse_budget("2x") == Budget("2x", scale=2.0)
    assert parse_budget("40000").refine_episodes == 40000
    for bad in ("fast", "0x", "-3", "5"):
        with pytest.raises(ValueError, match="--budget"):
            parse_budget(bad)


@pytest.mark.parametrize("extra, says", [
    (["--keep", "1.5"], "--keep: must be in (0, 1]"),
    (["--budget", "lots"], "--budget: expected smoke"),
    (["--leaves", "1,4"], "--leaves: leaf limits must be at least 2"),
    (["--checkpoint", "missing.zip"], "no SB3 checkpoint at missing.zip"),
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, extra, says):
    out = tmp_path / "out"
    argv = ["pipeline", "ToyLine-v0", "ppo", "--env-module", "tests.fixtures.toy_line",
            "-o", str(out), *extra]
    if "--checkpoint" not in extra:
        argv += ["--checkpoint", str(tmp_path / "x.zip")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_the_report_is_plain_data_of_the_run(agents, tmp_path):
    from ibt.pipeline.recommend import as_facts, recommend
    from ibt.tasks.catalogue import resolve_task

    rec = recommend(sb3_agent(resolve_task("ToyLine-v0"), "ppo", agents / "line.zip"),
                    budget=parse_budget("smoke"), leaf_limits=(4,), episodes=3,
                    cache_dir=tmp_path / "cache", progress=False)
    facts = json.loads(json.dumps(as_facts(rec)))
    assert facts["episodes"] == 3 and facts["leaf_limits"] == [4]
    assert facts["met"] == (facts["met_on_choice"] and facts["retention"] >= 95.0)
